"""The room cache: each room's voxel fields and sampled feature rows, written once and read back one room at a
time, so that training and evaluation hold one room's data at once however many rooms they loop over.

Layout (under `learn.cache_dir`): ``fields/<room>-<key>.npz`` (a room's `SceneFields`) and
``examples/<room>-<key>.npz`` (X, y, weight of `examples.room_examples`). Keys are digests of everything
the contents depend on, so a changed input is a new file, never a stale one:

* fields: the cloud's bytes, every setting but `learn`'s and `cluster`'s, and the source of the code that
  makes fields and features (`affordcore/geometry`, `mapping/pipeline.py`, `labels.py`, this file);
* examples: the fields' key, the label file's bytes, the affordance's skeleton, the feature layout's
  fingerprint and description, and how many negatives were sampled (the sampling's seed is the room's name).

Nothing is ever evicted: delete the folder to reclaim it (about 4 MB of fields and 1-5 MB of rows per room
and affordance at the defaults). Writes go to a temporary file renamed into place, so parallel workers and
interrupted runs never leave a half-written entry.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import cache
from pathlib import Path

import numpy as np

from ..geometry.columns import RESOLUTION, FineColumns
from ..geometry.fields import SceneFields, VoxelLattice
from ..geometry.scene import origins_file
from ..settings import Settings

FORMAT = 1
PACKAGE = Path(__file__).resolve().parents[1]
# the code whose output the cache holds: a change to any of it is a new key
SOURCES = ("geometry/*.py", "mapping/pipeline.py", "labels.py", "learn/cache.py", "learn/examples.py")


@cache
def code_digest() -> str:
    digest = hashlib.sha256()
    for pattern in SOURCES:
        for path in sorted(PACKAGE.glob(pattern)):
            digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def digest_of(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


def default_cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "affordmap"


class RoomCache:
    """A folder of rooms' fields and examples, by key (see the module's docstring)."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)

    @classmethod
    def from_settings(cls, settings: Settings) -> RoomCache:
        return cls(settings.learn.cache_dir or default_cache_dir())

    def fields_key(self, cloud: Path, settings: Settings) -> str:
        relevant = settings.model_dump(mode="json", exclude={"learn", "cluster"})
        origins = origins_file(cloud)
        seen_from = file_digest(origins) if origins.exists() else "no sensor positions"
        return digest_of(FORMAT, file_digest(cloud), seen_from, relevant, code_digest())

    def fields_path(self, name: str, key: str) -> Path:
        return self.folder / "fields" / f"{name}-{key}.npz"

    def examples_path(self, name: str, key: str) -> Path:
        return self.folder / "examples" / f"{name}-{key}.npz"


def save_fields(path: Path, fields: SceneFields) -> None:
    lattice = fields.lattice
    _save(
        path,
        origin=np.asarray(lattice.origin, dtype=np.float64),
        resolution=np.float64(lattice.resolution),
        shape=np.asarray(lattice.shape, dtype=np.int64),
        occupancy=fields.occupancy,
        distance=fields.distance,
        normals=fields.normals,
        footprint=np.asarray(fields.footprint, dtype=np.float64),
        steep_facing=np.str_(fields.steep_facing),
        normal_estimator=np.str_(fields.normal_estimator),
        **({} if fields.visibility is None else {"visibility": fields.visibility}),
        **({} if fields.soft_occupancy is None else {"soft_occupancy": fields.soft_occupancy}),
        **({} if fields.columns is None else _columns_arrays(fields.columns)),
    )


def _columns_arrays(columns: FineColumns) -> dict[str, np.ndarray]:
    return {"columns_origin": columns.origin, "columns_low": columns.low, "columns_high": columns.high}


def load_fields(path: Path) -> SceneFields:
    with np.load(path) as data:
        lattice = VoxelLattice(
            data["origin"], float(data["resolution"]), tuple(int(n) for n in data["shape"])
        )
        return SceneFields(
            lattice,
            data["occupancy"],
            data["distance"],
            data["normals"],
            tuple(float(v) for v in data["footprint"]),
            str(data["steep_facing"]),
            data["visibility"] if "visibility" in data else None,
            data["soft_occupancy"] if "soft_occupancy" in data else None,
            str(data["normal_estimator"]),
            FineColumns(data["columns_origin"], RESOLUTION, data["columns_low"], data["columns_high"])
            if "columns_low" in data
            else None,
        )


def save_examples(path: Path, X: np.ndarray, y: np.ndarray, weight: np.ndarray) -> None:
    _save(path, X=X, y=y, weight=weight)


def load_example_labels(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(y, weight) of stored examples, without reading their feature rows."""
    with np.load(path) as data:
        return data["y"], data["weight"]


def load_example_rows(path: Path) -> np.ndarray:
    with np.load(path) as data:
        return data["X"]


def _save(path: Path, **arrays) -> None:
    """Written whole or not at all: a temporary file of this process, renamed into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(temporary, "wb") as f:
        np.savez(f, **arrays)
    os.replace(temporary, path)
