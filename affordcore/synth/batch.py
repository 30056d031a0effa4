"""Generating a data set that survives interruption: `afford synth` resumes where it stopped, in parallel
processes.

Each room made leaves its report in ``<out>/.synth/<room>.json`` (written after the room's files, renamed into
place), with the options and the generator's digest it was made with. A run with the same options skips
every room whose report is there and makes the rest, so an interrupted run, or one asked for more rooms,
costs only the rooms missing; a room made with other options or by other generator code is made again.
Room i depends only on the seed and i (`dataset.make_room`), so the files are the same bytes as one
uninterrupted run's.

This file only decides which rooms to make and where: it is left out of `generator_digest`, so changing it
does not make `benchmarks/accuracy.py` generate its rooms again (which it does when the digest changes).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Iterator
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..parallel import map_in_processes
from .dataset import SynthOptions, _summary, make_room, summary_table

RESUME = ".synth"


def generator_digest() -> str:
    """A digest of the generator's source: every synth/*.py but this file."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        if path.name != Path(__file__).name:
            digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def synthesize(
    options: SynthOptions,
    out: Path,
    workers: int | None = None,
    on_room_done: Callable[[dict], None] | None = None,
) -> dict:
    """Every room not already made with these options (in `workers` processes, default one per core), then
    the summary of all of them; returns it. `on_room_done` hears each room's report, made now or before."""
    out = Path(out)
    (out / RESUME).mkdir(parents=True, exist_ok=True)
    made_with = {**asdict(options), "rooms": None, "generator": generator_digest()}
    made_with = json.loads(json.dumps(made_with))  # tuples as lists: as read back
    seeds = np.random.SeedSequence(options.seed).spawn(options.rooms)
    reports = {}
    for index in range(options.rooms):
        report = _made_before(out, options.room_name(index), made_with)
        if report is not None:
            reports[index] = report
            _tell(on_room_done, report)
    todo = [index for index in range(options.rooms) if index not in reports]
    workers = max(1, min(workers or os.cpu_count() or 1, len(todo) or 1))
    for index, report in _make(options, out, [(i, seeds[i]) for i in todo], workers):
        _write_json(out / RESUME / f"{report['room']}.json", {"made_with": made_with, "report": report})
        reports[index] = report
        _tell(on_room_done, report)
    summary = _summary(options, sorted(reports.values(), key=lambda r: r["room"]))
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (out / "summary.md").write_text(summary_table(summary))
    return summary


def _made_before(out: Path, name: str, made_with: dict) -> dict | None:
    """The room's report when it was made with these options and its files are all there."""
    path = out / RESUME / f"{name}.json"
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    files = [out / f"{name}.ply", out / f"{name}.labels.json", out / f"{name}.origins.npy"]
    if record.get("made_with") != made_with or not all(f.exists() for f in files):
        return None
    return record["report"]


def _make(options: SynthOptions, out: Path, jobs: list, workers: int) -> Iterator[tuple[int, dict]]:
    """(index, report) of each room made, in order, in parallel (`parallel.map_in_processes`)."""
    reports = map_in_processes(make_room, [(options, out, index, seed) for index, seed in jobs], workers)
    yield from zip((index for index, _ in jobs), reports)


def _write_json(path: Path, document: dict) -> None:
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    temporary.write_text(json.dumps(document) + "\n")
    os.replace(temporary, path)


def _tell(on_room_done: Callable[[dict], None] | None, report: dict) -> None:
    if on_room_done:
        on_room_done(report)
