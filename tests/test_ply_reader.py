"""The fast PLY path of `load_cloud` against plyfile: the same points and colours for ASCII and binary (both
byte orders), with and without colours, and a loud failure on truncated or malformed files."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from affordcore.geometry.scene import CloudError, _read_ascii_ply_vertices, load_cloud

N = 2_000


def _vertices(rng, colours: str | None, extra: bool = False, coordinate: str = "<f4") -> np.ndarray:
    fields = [("x", coordinate), ("y", coordinate), ("z", coordinate)]
    if extra:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"), ("intensity", "<f4")]
    if colours == "uchar":
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
    elif colours == "float":
        fields += [("red", "<f4"), ("green", "<f4"), ("blue", "<f4")]
    vertices = np.zeros(N, dtype=fields)
    for axis in "xyz":
        vertices[axis] = rng.uniform(-5.0, 5.0, N) * rng.choice([1e-3, 1.0, 1e3], N)
    vertices["x"][7] = np.nan  # dropped and counted, as from any reader
    vertices["z"][11] = np.inf
    for name, kind in fields[3:]:
        vertices[name] = rng.integers(0, 256, N) if kind == "u1" else rng.uniform(0.0, 1.0, N)
    return vertices


def _write(path, vertices, text: bool, byte_order: str = "<", faces: bool = False) -> None:
    elements = [PlyElement.describe(vertices, "vertex")]
    if faces:
        face = np.zeros(3, dtype=[("vertex_indices", "O")])
        face["vertex_indices"] = [np.array([0, 1, 2], dtype=np.int32)] * 3
        elements.append(PlyElement.describe(face, "face"))
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))


def _plyfile_reference(path) -> tuple[np.ndarray, np.ndarray | None]:
    """What the loader returned before the fast path: plyfile's values, converted as `_read_ply` does."""
    vertices = PlyData.read(str(path))["vertex"].data
    names = vertices.dtype.names
    points = np.column_stack([vertices[c].astype(np.float64) for c in "xyz"])
    if "red" not in names:
        return points, None
    rgb = np.column_stack([vertices[c].astype(np.float64) for c in ("red", "green", "blue")])
    scale = 255.0 if vertices["red"].dtype.kind in "ui" else 1.0
    return points, np.clip(rgb / scale, 0.0, 1.0).astype(np.float32)


def _same_as_plyfile(path) -> None:
    points, colours = _plyfile_reference(path)
    finite = np.isfinite(points).all(axis=1)
    cloud = load_cloud(path)
    assert cloud.dropped_nonfinite == int((~finite).sum()) == 2
    assert cloud.notes and "dropped 2 " in cloud.notes[0]
    np.testing.assert_array_equal(cloud.points, points[finite])
    if colours is None:
        assert cloud.colors is None
    else:
        np.testing.assert_array_equal(cloud.colors, colours[finite])


@pytest.mark.parametrize("colours", [None, "uchar", "float"])
@pytest.mark.parametrize("layout", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_same_as_plyfile(tmp_path, layout, colours):
    path = tmp_path / "room.ply"
    byte_order = ">" if layout.endswith("big_endian") else "<"
    _write(path, _vertices(np.random.default_rng(3), colours), layout == "ascii", byte_order)
    assert path.read_bytes().startswith(f"ply\nformat {layout} 1.0".encode())
    _same_as_plyfile(path)


@pytest.mark.parametrize("coordinate", ["<f4", "<f8"])
def test_ascii_fast_path_taken(tmp_path, coordinate):
    """The ASCII files a scanner writes go through the fast path (not plyfile's line loop), extra
    properties, double coordinates and a face element after the vertices included."""
    path = tmp_path / "mesh.ply"
    _write(path, _vertices(np.random.default_rng(4), "uchar", True, coordinate), text=True, faces=True)
    assert _read_ascii_ply_vertices(path) is not None
    _same_as_plyfile(path)


def test_ascii_last_line_without_newline(tmp_path):
    path = tmp_path / "open.ply"
    _write(path, _vertices(np.random.default_rng(5), None), text=True)
    path.write_bytes(path.read_bytes().rstrip(b"\n"))
    assert _read_ascii_ply_vertices(path) is not None
    _same_as_plyfile(path)


def test_ascii_colours_read_by_numpy_match(tmp_path):
    """Float colours are not what open3d reads as plyfile does: numpy parses the file, same values."""
    path = tmp_path / "float-colours.ply"
    _write(path, _vertices(np.random.default_rng(6), "float"), text=True)
    assert _read_ascii_ply_vertices(path) is not None
    _same_as_plyfile(path)


@pytest.mark.parametrize("cut", [0.5, 0.999])
@pytest.mark.parametrize("layout", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_truncated_fails_loudly(tmp_path, layout, cut):
    full = tmp_path / "full.ply"
    _write(
        full, _vertices(np.random.default_rng(7), "uchar"), layout == "ascii", ">" if "big" in layout else "<"
    )
    data = full.read_bytes()
    path = tmp_path / "cut.ply"
    path.write_bytes(data[: int(len(data) * cut)])
    with pytest.raises(CloudError, match="cut.ply"):
        load_cloud(path)


def test_truncated_at_a_line_end_fails_loudly(tmp_path):
    """Cut after a whole line: every line read looks fine, the count in the header says what is missing."""
    full = tmp_path / "full.ply"
    _write(full, _vertices(np.random.default_rng(8), None), text=True)
    data = full.read_bytes()
    path = tmp_path / "cut.ply"
    path.write_bytes(data[: data.rindex(b"\n", 0, len(data) * 2 // 3) + 1])
    assert _read_ascii_ply_vertices(path) is None
    with pytest.raises(CloudError, match="cut.ply"):
        load_cloud(path)


_HEADER = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"


@pytest.mark.parametrize(
    "header, body",
    [
        (_HEADER, "1 2 3\n4 5 6\n7 8.5.1 9\n1 1 1\n"),  # open3d stops here and leaves zeros behind
        (_HEADER, "1 2 3\n4 5 6\n7 8 9\n1 1 1.2.3\n"),  # the very last token
        (_HEADER, "1 2 3\n4 5\n6 7 8 9\n1 1 1\n"),  # the right count of numbers, on the wrong lines
        (_HEADER, "1 2 3\n4 5 6\n\n7 8 9\n"),  # a blank line
        (_HEADER + "property uchar red\n", "1 2 3 4\n4 5 6 300\n7 8 9 1\n1 1 1 1\n"),  # 300 is no uchar
        (_HEADER + "property uchar red\n", "1 2 3 4\n4 5 6 1.5\n7 8 9 1\n1 1 1 1\n"),
    ],
    ids=["bad-token", "bad-last-token", "misaligned-lines", "blank-line", "uchar-overflow", "uchar-fraction"],
)
def test_malformed_ascii_fails_loudly(tmp_path, header, body):
    path = tmp_path / "broken.ply"
    path.write_text(header + "end_header\n" + body)
    assert _read_ascii_ply_vertices(path) is None
    with pytest.raises(CloudError, match="broken.ply"):
        load_cloud(path)


def test_last_point_at_the_origin_still_read(tmp_path):
    """A last vertex at (0, 0, 0) looks like open3d stopping early: numpy parses the file instead."""
    path = tmp_path / "origin.ply"
    path.write_text(_HEADER + "end_header\n1 2 3\n4 5 6\n7 8 9\n0 0 0\n")
    np.testing.assert_array_equal(load_cloud(path).points, [[1, 2, 3], [4, 5, 6], [7, 8, 9], [0, 0, 0]])
