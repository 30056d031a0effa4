"""The assembler's state on disk, so a restart loses no accepted frame.

Two files in one folder: a snapshot (`state.npz`: the global map, the trajectory, the pose guess and gravity
so far), rewritten atomically every `assembler.checkpoint_period` seconds, and a journal (`journal.bin`) to
which every accepted frame's record is appended and flushed before anything is published about it. A restart
loads the snapshot and replays the journal; a record cut short by a kill is a frame that was never accepted
(its pose was not published) and is dropped. Records carry their frame number, so a journal that outlived
its snapshot (a kill between the two writes) replays nothing twice. A flush survives the process, not the
machine: what the operating system had not written at a power cut is lost back to the last snapshot, which
is synced to disk.
"""

from __future__ import annotations

import io
import os
import struct
from pathlib import Path

import numpy as np

from .assembler import Assembler, FrameRecord

_LENGTH = struct.Struct("<Q")


def _arrays(**values) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **values)
    return buffer.getvalue()


def _encode(record: FrameRecord) -> bytes:
    body = _arrays(
        index=record.index,
        stamp=record.stamp,
        pose=record.pose,
        guess=np.empty((0, 4)) if record.guess is None else record.guess,
        gravity=record.gravity,
        map_points=np.empty((0, 3)) if record.map_points is None else record.map_points,
        map_weights=np.empty(0) if record.map_weights is None else record.map_weights,
        keyframe=record.map_points is not None,
    )
    return _LENGTH.pack(len(body)) + body


def _decode(body: bytes) -> FrameRecord:
    with np.load(io.BytesIO(body)) as data:
        return FrameRecord(
            index=int(data["index"]),
            stamp=float(data["stamp"]),
            pose=data["pose"],
            guess=data["guess"] if data["guess"].size else None,
            gravity=data["gravity"],
            map_points=data["map_points"] if bool(data["keyframe"]) else None,
            # journals written before the map kept running means: one observation a point
            map_weights=data["map_weights"] if "map_weights" in data and data["map_weights"].size else None,
        )


def read_journal(path: Path) -> list[FrameRecord]:
    """The journal's whole records, in order (a trailing partial one is left out)."""
    records, data = [], path.read_bytes() if path.exists() else b""
    at = 0
    while at + _LENGTH.size <= len(data):
        (length,) = _LENGTH.unpack_from(data, at)
        if at + _LENGTH.size + length > len(data):
            break
        records.append(_decode(data[at + _LENGTH.size : at + _LENGTH.size + length]))
        at += _LENGTH.size + length
    return records


class AssemblerStore:
    """Snapshot and journal of one assembler in `folder` (created when missing)."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.snapshot_path = self.folder / "state.npz"
        self.journal_path = self.folder / "journal.bin"
        # the world frame of the last map published (world_from_odom), kept as it changes: a restart levels
        # its first map as the last one was, not anew, so the robot's world frame does not move
        self.alignment_path = self.folder / "world_from_odom.npy"
        self._saved_alignment = None  # the world_from_odom in that file (the same object: not written again)
        self._journal = None

    def restore(self, assembler: Assembler) -> int:
        """Load the snapshot and replay the journal onto a fresh `assembler`; returns the frames restored.
        Afterwards the journal is open for `append`."""
        if self.snapshot_path.exists():
            with np.load(self.snapshot_path) as data:
                assembler.load_state(data)
        in_snapshot = assembler.frames
        records = [record for record in read_journal(self.journal_path) if record.index >= in_snapshot]
        for record in records:
            if record.index == assembler.frames:
                assembler.apply(record)
        if assembler.frames:
            assembler.resume()
            if self.alignment_path.exists():
                assembler.world_from_odom = self._saved_alignment = np.load(self.alignment_path)
        self._rewrite_journal(records)  # the same records without a cut-short tail
        return assembler.frames

    def save_alignment(self, world_from_odom: np.ndarray) -> None:
        """Keep the world frame of the map just published (atomically: a kill leaves the old or the new); a
        map levelled as the last one was (the same matrix) writes nothing."""
        if world_from_odom is self._saved_alignment:
            return
        temporary = self.alignment_path.with_suffix(".tmp.npy")
        np.save(temporary, np.asarray(world_from_odom, dtype=np.float64))
        os.replace(temporary, self.alignment_path)
        self._saved_alignment = world_from_odom

    def append(self, record: FrameRecord) -> None:
        """Journal one accepted frame (flushed: it survives a kill of this process)."""
        if self._journal is None:
            self._journal = open(self.journal_path, "ab")
        self._journal.write(_encode(record))
        self._journal.flush()

    def snapshot(self, assembler: Assembler) -> None:
        """Write the whole state atomically and start an empty journal."""
        temporary = self.snapshot_path.with_suffix(".tmp.npz")
        with open(temporary, "wb") as file:
            np.savez(file, **assembler.state_arrays())
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, self.snapshot_path)
        self.close()
        self.journal_path.write_bytes(b"")  # all of it is in the snapshot (a kill before this: see restore)

    def clear(self) -> None:
        """Forget the state: no snapshot, an empty journal (a restart then begins a new map)."""
        self.close()
        self.snapshot_path.unlink(missing_ok=True)
        self.alignment_path.unlink(missing_ok=True)
        self._saved_alignment = None
        self.journal_path.write_bytes(b"")

    def close(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None

    def _rewrite_journal(self, records: list[FrameRecord]) -> None:
        self.close()
        temporary = self.journal_path.with_suffix(".tmp")
        temporary.write_bytes(b"".join(_encode(record) for record in records))
        os.replace(temporary, self.journal_path)
