"""Point clouds in, one `Cloud` out: every supported file format, with clear errors for bad input.

Formats: PLY (binary through plyfile, memory-mapped; ASCII through a vectorised numpy reader that checks
the file's structure first, with plyfile for any file it does not take: both fail loudly on a truncated or
malformed file, where open3d returns the header's number of points filled with zeros), PCD (pypcd4;
binary, ASCII, binary_compressed), XYZ / PTS / TXT text (``x y z``, ``x y z r g b``, or PTS ``x y z
intensity r g b`` with an optional point-count first line), NPY (an (N, 3) or (N, 6) array) and raw
little-endian float32 BIN (``x y z`` or ``x y z r g b`` per point). Colours come back as floats in [0, 1].
Points with a NaN or infinite coordinate are dropped, counted and noted (`Cloud.notes`).
"""

from __future__ import annotations

import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

SUPPORTED_SUFFIXES = (".ply", ".pcd", ".xyz", ".pts", ".txt", ".npy", ".bin")


class CloudError(ValueError):
    """A cloud file that cannot be used; the message names the file and the problem."""


@dataclass
class Cloud:
    """Points (N, 3) float64 in metres, optional colours (N, 3) float32 in [0, 1], and optionally where the
    sensor stood when it saw them (`origins`, (M, 3) in the points' frame: what tells space seen through
    from space never seen, `geometry.visibility`)."""

    points: np.ndarray
    colors: np.ndarray | None = None
    source: str = "<memory>"
    dropped_nonfinite: int = 0
    notes: list[str] = field(default_factory=list)
    origins: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(self.points, dtype=np.float64)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise CloudError(f"{self.source}: points must be an (N, 3) array, got shape {self.points.shape}")
        if self.colors is not None:
            self.colors = np.ascontiguousarray(self.colors, dtype=np.float32)
            if self.colors.shape != self.points.shape:
                raise CloudError(f"{self.source}: {len(self.colors)} colours for {len(self.points)} points")
        if self.origins is not None:
            self.origins = checked_origins(self.origins, self.source)

    def __len__(self) -> int:
        return len(self.points)

    def transformed(self, transform: np.ndarray) -> Cloud:
        """The same cloud with a 4 x 4 rigid transform applied to its points."""

        def moved(xyz: np.ndarray) -> np.ndarray:
            return xyz @ transform[:3, :3].T + transform[:3, 3]

        origins = None if self.origins is None else moved(self.origins)
        return Cloud(
            moved(self.points), self.colors, self.source, self.dropped_nonfinite, list(self.notes), origins
        )

    def with_points(self, points: np.ndarray, colors: np.ndarray | None) -> Cloud:
        """The same cloud (source, notes, sensor positions) with other points, e.g. thinned."""
        return Cloud(points, colors, self.source, self.dropped_nonfinite, list(self.notes), self.origins)


def origins_file(cloud: str | os.PathLike) -> Path:
    """Where a cloud file's sensor positions are looked for: ``<stem>.origins.npy`` beside it (what
    `afford synth` writes)."""
    path = Path(cloud)
    return path.with_name(path.stem + ".origins.npy")


def load_origins(path: str | os.PathLike) -> np.ndarray | None:
    """Sensor positions (M, 3) from a .npy array or a text table (x y z per row), None for an empty (0, 3)
    array (a cloud sampled from every surface had no sensor); `CloudError` naming the file and the
    problem."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npy":
            array = np.load(path, allow_pickle=False)
        else:  # read once: the delimiter is a comma when the table has any
            text = path.read_text(errors="replace")
            delimiter = "," if "," in text else None
            array = np.loadtxt(text.splitlines(), dtype=np.float64, ndmin=2, delimiter=delimiter)
    except (OSError, ValueError) as error:
        raise CloudError(f"{path}: cannot read sensor positions: {error}") from error
    if np.shape(array) == (0, 3):
        return None
    return checked_origins(array, str(path))


def checked_origins(origins, source: str) -> np.ndarray:
    """(M, 3) float64 finite sensor positions, M >= 1, or a `CloudError` that says what is wrong."""
    array = np.asarray(origins, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or not len(array):
        raise CloudError(
            f"{source}: sensor positions must be an (M, 3) array with M >= 1, got shape {array.shape}"
        )
    if not np.isfinite(array).all():
        raise CloudError(f"{source}: sensor positions must be finite")
    return np.ascontiguousarray(array)


def load_cloud(path: str | os.PathLike, bin_columns: int | None = None) -> Cloud:
    """Read a cloud file of any supported format; raise `CloudError` naming the file on bad input.

    ``bin_columns`` (3 or 6) says how a raw ``.bin`` is laid out; by default it is inferred (6 only when the
    last three columns read as colours).
    """
    path = Path(path)
    if not path.exists():
        raise CloudError(f"{path}: no such file")
    if not path.is_file():
        raise CloudError(f"{path}: not a file")
    if not os.access(path, os.R_OK):
        raise CloudError(f"{path}: not readable (permission denied)")
    suffix = path.suffix.lower()
    readers = {
        ".ply": _read_ply,
        ".pcd": _read_pcd,
        ".xyz": _read_text,
        ".pts": _read_text,
        ".txt": _read_text,
        ".npy": _read_npy,
        ".bin": lambda p: _read_bin(p, bin_columns),
    }
    if suffix not in readers:
        raise CloudError(
            f"{path}: unknown cloud format {suffix!r}; supported: {', '.join(SUPPORTED_SUFFIXES)}"
        )
    if path.stat().st_size == 0:
        raise CloudError(f"{path}: empty file")
    try:
        points, colors = readers[suffix](path)
    except CloudError:
        raise
    except Exception as error:  # a parser's own message, with the file named
        raise CloudError(f"{path}: cannot read as {suffix[1:].upper()}: {error}") from error
    cloud = _finish(path, points, colors)
    beside = origins_file(path)
    if beside.exists():  # written with the cloud (afford synth): it says which space was seen through
        cloud.origins = load_origins(beside)
    return cloud


def _finish(path: Path, points: np.ndarray, colors: np.ndarray | None) -> Cloud:
    finite = np.isfinite(points).all(axis=1)
    dropped = int((~finite).sum())
    if dropped:
        points = points[finite]
        colors = colors[finite] if colors is not None else None
    if len(points) == 0:
        detail = f" (all {dropped} points had NaN or infinite coordinates)" if dropped else ""
        raise CloudError(f"{path}: the cloud has no points{detail}")
    cloud = Cloud(points, colors, str(path), dropped)
    if dropped:  # said, never silent: a reader that writes NaN for no return (organised scans) loses points
        cloud.notes.append(f"dropped {dropped:,} of {len(finite):,} points that are not finite (NaN or inf)")
    return cloud


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    _check_header(path)
    vertices = _read_ascii_ply_vertices(path)
    if vertices is None:  # binary (memory-mapped, not read row by row), or an ASCII file the fast path left
        from plyfile import PlyData

        vertices = PlyData.read(str(path))["vertex"].data
    names = tuple(vertices.dtype.names or ()) if hasattr(vertices, "dtype") else tuple(vertices)
    if not {"x", "y", "z"} <= set(names):
        raise CloudError(f"{path}: the PLY vertices have no x, y, z properties (have {', '.join(names)})")
    points = np.column_stack([vertices[c].astype(np.float64) for c in ("x", "y", "z")])
    channels = next((c for c in (("red", "green", "blue"), ("r", "g", "b")) if set(c) <= set(names)), None)
    if channels is None:
        return points, None
    rgb = np.column_stack([vertices[c].astype(np.float64) for c in channels])
    scale = 255.0 if vertices[channels[0]].dtype.kind in "ui" else 1.0
    return points, np.clip(rgb / scale, 0.0, 1.0).astype(np.float32)


# PLY's scalar types (both spellings) as numpy types; list properties are left to plyfile
_PLY_TYPES = {
    **dict.fromkeys(("char", "int8"), np.int8),
    **dict.fromkeys(("uchar", "uint8"), np.uint8),
    **dict.fromkeys(("short", "int16"), np.int16),
    **dict.fromkeys(("ushort", "uint16"), np.uint16),
    **dict.fromkeys(("int", "int32"), np.int32),
    **dict.fromkeys(("uint", "uint32"), np.uint32),
    **dict.fromkeys(("float", "float32"), np.float32),
    **dict.fromkeys(("double", "float64"), np.float64),
}
_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[[9, 10, 11, 12, 13, 32]] = True


def _read_ascii_ply_vertices(path: Path) -> dict[str, np.ndarray] | None:
    """The vertex properties of an ASCII PLY, {name: values of the declared type}, with plyfile's values
    (tests/test_scene.py compares them), about 15x faster: numpy parses the numbers in one call instead of
    plyfile's Python loop over lines (5 s for a 470k-point room).

    The structure is checked before a number is read: the vertex section must be exactly the header's
    count of lines with one token per property on every line, and every token must parse. Anything else
    (and any file this reader does not take: binary, a vertex element with list properties or after
    another element, CRLF headers) returns None, and plyfile reads the file or says what is wrong with it;
    such a file never comes back as points filled with garbage."""
    with path.open("rb") as handle:
        head = handle.read(1 << 16)
    end = head.find(b"end_header\n")
    if end < 0 or b"\r" in head[:end]:
        return None
    lines = head[:end].decode("ascii", errors="replace").split("\n")
    if len(lines) < 2 or lines[1].split() != ["format", "ascii", "1.0"]:
        return None
    elements: list[tuple[str, int, list[tuple[str, type]]]] = []
    for line in lines[2:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and len(words) == 3 and words[1] in _PLY_TYPES and elements:
            elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
        elif words[0] == "property" and words[1:2] == ["list"] and len(elements) > 1:
            continue  # faces after the vertices: not read
        else:  # a list property of the vertices, or a header this reader does not know
            return None
    if not elements or elements[0][0] != "vertex" or not elements[0][2]:
        return None
    _, count, properties = elements[0]
    names = [name for name, _ in properties]
    if len(set(names)) != len(names):
        return None
    body = np.fromfile(path, dtype=np.uint8, offset=end + len(b"end_header\n"))
    if count == 0:
        return None
    # the vertex section: the first `count` lines (the last one may lack its newline when nothing follows)
    newlines = np.flatnonzero(body == 10)
    if len(newlines) >= count:
        section_end = int(newlines[count - 1])
    elif len(newlines) == count - 1 and len(elements) == 1 and not _WHITESPACE[body[-1]]:
        section_end = len(body)
        newlines = np.append(newlines, len(body))
    else:
        return None
    section = body[:section_end]
    blank = _WHITESPACE[section]
    starts = np.flatnonzero(~blank[1:] & blank[:-1]) + 1
    if len(section) and not blank[0]:
        starts = np.concatenate([[0], starts])
    width = len(properties)
    if len(starts) != count * width:
        return None
    # every line holds exactly `width` tokens: the first token of line i starts after line i - 1's newline,
    # its last one before line i's (token starts are sorted, so no line can hold more or fewer)
    firsts, lasts = starts[::width], starts[width - 1 :: width]
    line_ends = newlines[:count]
    if np.any(lasts > line_ends) or np.any(firsts[1:] <= line_ends[:-1]):
        return None
    # numpy's parser, not open3d's 3x faster reader: importing open3d costs more than the parse saves
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy only warns when a token does not parse
        try:
            values = np.fromstring(section.tobytes(), dtype=np.float64, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    if len(values) != count * width:
        return None
    table = values.reshape(count, width)
    columns = {}
    for k, (name, kind) in enumerate(properties):
        column = table[:, k]
        if np.dtype(kind).kind in "ui":  # plyfile refuses 1.5 or 300 for a uchar: so does this reader
            limits = np.iinfo(kind)
            whole = np.all(column == np.round(column))
            if not (whole and column.min() >= limits.min and column.max() <= limits.max):
                return None
        columns[name] = column.astype(kind)
    return columns


def _read_pcd(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """A PCD file's x, y, z (and rgb), ascii, binary or binary_compressed, through pypcd4 (tests/test_scene.py
    reads open3d's PCD files of every encoding)."""
    from pypcd4 import PointCloud

    _check_header(path)
    try:
        pcd = PointCloud.from_path(path)
        points = pcd.numpy(("x", "y", "z")).astype(np.float64)
    except Exception as error:  # noqa: BLE001 - a malformed file raises whatever its parser meets first
        raise CloudError(
            f"{path}: not a readable PCD file: truncated or malformed ({type(error).__name__}: {error})"
        ) from None
    if len(points) != pcd.metadata.points:
        raise CloudError(
            f"{path}: truncated: its header says {pcd.metadata.points:,} points, it holds {len(points):,}"
        )
    if len(points) == 0:
        raise CloudError(
            f"{path}: no points could be read (the file is empty, truncated or not a point cloud)"
        )
    colors = None
    if "rgb" in pcd.fields:
        colors = (PointCloud.decode_rgb(pcd.numpy(("rgb",)).ravel()) / 255.0).astype(np.float32)
    return points, colors


def _check_header(path: Path) -> None:
    """Readers given a file of the wrong kind fail obscurely (open3d only warns); say what is wrong
    instead."""
    with path.open("rb") as handle:
        head = handle.read(64)
    if path.suffix.lower() == ".ply" and not head.startswith(b"ply"):
        raise CloudError(f"{path}: not a PLY file (it does not start with 'ply')")
    if path.suffix.lower() == ".pcd" and not any(key in head for key in (b"VERSION", b"FIELDS", b"# .PCD")):
        raise CloudError(f"{path}: not a PCD file (no PCD header)")


def _read_text(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    with path.open("r", errors="replace") as handle:
        lines = [line for line in handle if line.strip() and not line.lstrip().startswith(("#", "//"))]
    if lines and len(re.split(r"[\s,]+", lines[0].strip())) == 1:  # PTS files start with the point count
        lines = lines[1:]
    if not lines:
        raise CloudError(f"{path}: the cloud has no points")
    try:
        table = np.loadtxt(lines, dtype=np.float64, ndmin=2, delimiter=None if "," not in lines[0] else ",")
    except ValueError as error:
        raise CloudError(f"{path}: not a table of numbers ({error})") from error
    return _split_columns(path, table)


def _read_npy(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    array = np.load(path, allow_pickle=False)
    if array.dtype.names:  # a structured array with x, y, z (and r, g, b) fields
        names = array.dtype.names
        if not {"x", "y", "z"} <= set(names):
            raise CloudError(f"{path}: structured array without x, y, z fields (has {', '.join(names)})")
        columns = ["x", "y", "z"] + (
            [c for c in ("r", "g", "b") if c in names] if {"r", "g", "b"} <= set(names) else []
        )
        array = np.stack([array[c].astype(np.float64) for c in columns], axis=1)
    if array.ndim != 2 or array.shape[1] not in (3, 6):
        raise CloudError(f"{path}: expected an (N, 3) or (N, 6) array, got shape {array.shape}")
    return _split_columns(path, array.astype(np.float64))


def _read_bin(path: Path, columns: int | None) -> tuple[np.ndarray, np.ndarray | None]:
    size = path.stat().st_size
    if size % 4:
        raise CloudError(f"{path}: {size} bytes is not a whole number of float32 values")
    raw = np.fromfile(path, dtype="<f4")
    if columns is None:
        columns = 6 if len(raw) % 6 == 0 and _looks_like_colors(raw.reshape(-1, 6)[:, 3:]) else 3
    if columns not in (3, 6):
        raise CloudError(
            f"{path}: a .bin cloud has 3 (x y z) or 6 (x y z r g b) float32 columns, not {columns}"
        )
    if len(raw) % columns:
        raise CloudError(
            f"{path}: {path.stat().st_size} bytes is not a whole number of {columns}-float32 points"
        )
    return _split_columns(path, raw.reshape(-1, columns).astype(np.float64))


def _looks_like_colors(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values).all(axis=1)]
    if len(finite) == 0:
        return False
    in_unit = finite.min() >= 0 and finite.max() <= 1
    in_bytes = finite.min() >= 0 and finite.max() <= 255 and np.all(finite == np.round(finite))
    return bool(in_unit or in_bytes)


def _split_columns(path: Path, table: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    n_columns = table.shape[1]
    if n_columns == 3:
        return table, None
    if n_columns == 6:
        rgb = table[:, 3:6]
    elif n_columns == 7:  # PTS: x y z intensity r g b
        rgb = table[:, 4:7]
    elif n_columns == 4:  # x y z intensity: no colour
        return table[:, :3], None
    else:
        raise CloudError(
            f"{path}: expected 3, 4, 6 or 7 columns (x y z [intensity] [r g b]), got {n_columns}"
        )
    finite_rgb = rgb[np.isfinite(rgb).all(axis=1)]
    scale = 255.0 if len(finite_rgb) and finite_rgb.max() > 1.0 else 1.0
    return table[:, :3], np.clip(rgb / scale, 0.0, 1.0).astype(np.float32)


def voxel_thin(
    points: np.ndarray, voxel: float, colors: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """The mean point (and colour) of each occupied voxel, in a fixed order: an even spread whatever the scan
    density, and deterministic (unlike a hash map's order)."""
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    span = keys.max(axis=0) + 1
    flat = (keys[:, 0] * span[1] + keys[:, 1]) * span[2] + keys[:, 2]
    _, inverse, counts = np.unique(flat, return_inverse=True, return_counts=True)

    def mean(values: np.ndarray) -> np.ndarray:
        return (
            np.stack([np.bincount(inverse, values[:, k]) for k in range(values.shape[1])], axis=1)
            / counts[:, None]
        )

    return mean(points), None if colors is None else mean(colors.astype(np.float64)).astype(np.float32)


def save_cloud(path: str | os.PathLike, cloud: Cloud) -> None:
    """Write a cloud as binary PLY (float32 x y z, uchar colours), PCD or NPY, chosen by the suffix.

    PLY goes through plyfile: the same cloud gives the same bytes, so generated data sets are reproducible.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        table = cloud.points if cloud.colors is None else np.hstack([cloud.points, cloud.colors])
        np.save(path, table)
    elif suffix == ".ply":
        from plyfile import PlyData, PlyElement

        fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
        if cloud.colors is not None:
            fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        vertices = np.empty(len(cloud), dtype=fields)
        for k, axis in enumerate("xyz"):
            vertices[axis] = cloud.points[:, k]
        if cloud.colors is not None:
            rgb = np.clip(np.round(cloud.colors * 255), 0, 255).astype(np.uint8)
            for k, channel in enumerate(("red", "green", "blue")):
                vertices[channel] = rgb[:, k]
        PlyData([PlyElement.describe(vertices, "vertex")], byte_order="<").write(str(path))
    elif suffix == ".pcd":
        from pypcd4 import PointCloud

        # float32 x, y, z (and PCL's packed rgb), as PCL and every PCD reader expect them
        columns = [np.asarray(cloud.points, dtype=np.float32)]
        if cloud.colors is not None:
            rgb = np.clip(np.round(cloud.colors * 255), 0, 255).astype(np.uint8)
            columns.append(PointCloud.encode_rgb(rgb).reshape(-1, 1))
        names = ("x", "y", "z", "rgb")[: 3 + (cloud.colors is not None)]
        PointCloud.from_points(np.hstack(columns), names, (np.float32,) * len(names)).save(path)  # binary
    else:
        raise CloudError(f"{path}: can only write .ply, .pcd or .npy")


def thin_huge_cloud(cloud: Cloud, max_points: int, first_voxel: float) -> tuple[Cloud, str | None]:
    """A cloud over `max_points` is voxel-thinned (at `first_voxel`, doubled until it fits), so that a dense
    scan cannot exhaust memory; returns the cloud and a warning that says what was done (None if nothing)."""
    if len(cloud) <= max_points:
        return cloud, None
    voxel = first_voxel
    points, colors = voxel_thin(cloud.points, voxel, cloud.colors)
    while len(points) > max_points:
        voxel *= 2
        points, colors = voxel_thin(cloud.points, voxel, cloud.colors)
    warning = (
        f"{cloud.source}: {len(cloud):,} points is over the {max_points:,} limit; thinned to {len(points):,} "
        f"at {voxel * 100:.0f} mm voxels (AFFORD_MAP__MAX_POINTS raises the limit)"
    )
    return cloud.with_points(points, colors), warning
