"""load_cloud: every format round-trips, bad points are dropped and counted, bad files give clear errors."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from affordcore.geometry.scene import SUPPORTED_SUFFIXES, Cloud, CloudError, load_cloud, save_cloud

N = 300


@pytest.fixture
def points() -> np.ndarray:
    """A small room-sized cloud with negative and positive coordinates (metres)."""
    rng = np.random.default_rng(7)
    return rng.uniform([-3.0, -2.0, -0.1], [4.0, 5.0, 2.6], size=(N, 3))


@pytest.fixture
def colors255() -> np.ndarray:
    """Integer 0-255 colours, including both ends of the range."""
    rng = np.random.default_rng(8)
    colors = rng.integers(0, 256, size=(N, 3)).astype(np.float64)
    colors[0] = [0, 0, 0]
    colors[1] = [255, 255, 255]
    return colors


def _write_table(path: Path, table: np.ndarray, header: str | None = None, delimiter: str = " ") -> None:
    lines = [] if header is None else [header]
    lines += [delimiter.join(repr(float(v)) for v in row) for row in table]
    path.write_text("\n".join(lines) + "\n")


def _check(
    cloud: Cloud, points: np.ndarray, colors: np.ndarray | None, atol: float = 1e-9, color_atol: float = 1e-6
):
    assert isinstance(cloud, Cloud)
    assert cloud.points.shape == points.shape
    assert cloud.points.dtype == np.float64
    np.testing.assert_allclose(cloud.points, points, atol=atol, rtol=0)
    if colors is None:
        assert cloud.colors is None
    else:
        assert cloud.colors is not None
        assert cloud.colors.shape == points.shape
        assert cloud.colors.min() >= 0.0 and cloud.colors.max() <= 1.0
        np.testing.assert_allclose(cloud.colors, colors, atol=color_atol, rtol=0)
    assert cloud.dropped_nonfinite == 0
    assert cloud.notes == []


# --- round trips --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("with_colors", [False, True])
def test_ply_binary_round_trip_via_save_cloud(tmp_path, points, colors255, with_colors):
    colors = colors255 / 255.0 if with_colors else None
    path = tmp_path / "room.ply"
    save_cloud(path, Cloud(points, colors))
    assert path.read_bytes().startswith(b"ply\nformat binary")
    cloud = load_cloud(path)
    _check(cloud, points, colors, atol=2e-6, color_atol=0.5 / 255 + 1e-6)  # PLY stores float32 coordinates
    assert cloud.source == str(path)


def test_npy_round_trip_via_save_cloud(tmp_path, points, colors255):
    path = tmp_path / "room.npy"
    save_cloud(path, Cloud(points, colors255 / 255.0))
    _check(load_cloud(path), points, colors255 / 255.0)


def test_ply_ascii_written_by_hand(tmp_path, points, colors255):
    path = tmp_path / "hand.ply"
    header = (
        "ply\nformat ascii 1.0\ncomment written by hand\n"
        f"element vertex {N}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    rows = [
        f"{x:.6f} {y:.6f} {z:.6f} {int(r)} {int(g)} {int(b)}"
        for (x, y, z), (r, g, b) in zip(points, colors255)
    ]
    path.write_text(header + "\n".join(rows) + "\n")
    _check(load_cloud(path), points, colors255 / 255.0, atol=2e-6, color_atol=1e-6)


def test_ply_ascii_without_colours(tmp_path, points):
    path = tmp_path / "plain.ply"
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {N}\n"
        "property double x\nproperty double y\nproperty double z\nend_header\n"
    )
    path.write_text(header + "\n".join(" ".join(repr(float(v)) for v in row) for row in points) + "\n")
    _check(load_cloud(path), points, None, atol=1e-12)


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_pcd_written_by_open3d(tmp_path, points, colors255, mode):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.colors = o3d.utility.Vector3dVector(colors255 / 255.0)
    path = tmp_path / f"room_{mode}.pcd"
    assert o3d.io.write_point_cloud(
        str(path), pcd, write_ascii=(mode == "ascii"), compressed=(mode == "binary_compressed")
    )
    assert f"DATA {mode}".encode() in path.read_bytes()[:400]
    # PCD stores float32 coordinates and packed 8-bit colours.
    _check(load_cloud(path), points, colors255 / 255.0, atol=1e-5, color_atol=0.5 / 255 + 1e-6)


def test_pcd_without_colours(tmp_path, points):
    import open3d as o3d

    path = tmp_path / "plain.pcd"
    assert o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    _check(load_cloud(path), points, None, atol=1e-5)


def test_pcd_files_are_read_and_written_without_open3d(tmp_path, points, colors255):
    """open3d is afford synth's alone (the learn extra): a PCD goes in and out of a core install, colours and
    all, and open3d reads what it writes."""
    import subprocess
    import sys

    from affordcore.geometry.scene import Cloud, save_cloud

    path = tmp_path / "room.pcd"
    save_cloud(path, Cloud(points, colors255.astype(np.float32) / 255))
    script = (
        "import sys; from affordcore.geometry.scene import load_cloud; "
        f"c = load_cloud({str(path)!r}); print(len(c.points), c.colors.shape, 'open3d' in sys.modules)"
    )
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout.split()[-1] == "False", run.stdout + run.stderr
    _check(load_cloud(path), points, colors255 / 255.0, atol=1e-5, color_atol=0.5 / 255 + 1e-6)
    import open3d as o3d

    np.testing.assert_allclose(np.asarray(o3d.io.read_point_cloud(str(path)).points), points, atol=1e-5)


def test_xyz_three_columns(tmp_path, points):
    path = tmp_path / "room.xyz"
    _write_table(path, points)
    _check(load_cloud(path), points, None)


def test_xyz_six_columns_with_byte_colours(tmp_path, points, colors255):
    path = tmp_path / "room.xyz"
    _write_table(path, np.hstack([points, colors255]))
    cloud = load_cloud(path)
    _check(cloud, points, colors255 / 255.0)
    assert cloud.colors.dtype == np.float32


def test_xyz_six_columns_with_unit_colours(tmp_path, points, colors255):
    path = tmp_path / "room.xyz"
    _write_table(path, np.hstack([points, colors255 / 255.0]))
    _check(load_cloud(path), points, colors255 / 255.0)


def test_pts_with_count_line_and_intensity(tmp_path, points, colors255):
    rng = np.random.default_rng(9)
    intensity = rng.integers(-2048, 2048, size=(N, 1)).astype(float)  # PTS intensity is not a colour
    path = tmp_path / "scan.pts"
    _write_table(path, np.hstack([points, intensity, colors255]), header=str(N))
    _check(load_cloud(path), points, colors255 / 255.0)


def test_txt_with_comment_header(tmp_path, points, colors255):
    path = tmp_path / "room.txt"
    _write_table(path, np.hstack([points, colors255]), header="# x y z r g b")
    _check(load_cloud(path), points, colors255 / 255.0)


def test_txt_comma_separated(tmp_path, points):
    """The reader accepts comma-separated rows: none of them may be lost (e.g. mistaken for a PTS count
    line)."""
    path = tmp_path / "room.txt"
    _write_table(path, points, header="# x,y,z", delimiter=",")
    _check(load_cloud(path), points, None)


def test_npy_three_columns(tmp_path, points):
    path = tmp_path / "room.npy"
    np.save(path, points)
    _check(load_cloud(path), points, None)


def test_npy_six_columns_byte_colours(tmp_path, points, colors255):
    path = tmp_path / "room.npy"
    np.save(path, np.hstack([points, colors255]).astype(np.float32))
    _check(load_cloud(path), points, colors255 / 255.0, atol=1e-5)


def test_npy_structured_xyz_rgb(tmp_path, points, colors255):
    table = np.zeros(N, dtype=[("x", "f8"), ("y", "f8"), ("z", "f8"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    for i, name in enumerate("xyz"):
        table[name] = points[:, i]
    for i, name in enumerate("rgb"):
        table[name] = colors255[:, i]
    path = tmp_path / "room.npy"
    np.save(path, table)
    _check(load_cloud(path), points, colors255 / 255.0)


def test_bin_three_columns_auto(tmp_path, points):
    # N is even, so the file is also a whole number of 6-float rows: auto-detection must look at the values.
    assert (N * 3) % 6 == 0
    path = tmp_path / "scan.bin"
    points.astype("<f4").tofile(path)
    _check(load_cloud(path), points, None, atol=1e-6)


def test_bin_three_columns_odd_count(tmp_path, points):
    path = tmp_path / "scan.bin"
    points[:-1].astype("<f4").tofile(path)  # 299 points: 897 floats, not a multiple of 6
    _check(load_cloud(path), points[:-1], None, atol=1e-6)


@pytest.mark.parametrize("scale", [255.0, 1.0], ids=["byte-colours", "unit-colours"])
def test_bin_six_columns_auto(tmp_path, points, colors255, scale):
    path = tmp_path / "scan.bin"
    np.hstack([points, colors255 / 255.0 * scale]).astype("<f4").tofile(path)
    _check(load_cloud(path), points, colors255 / 255.0, atol=1e-6)


def test_bin_explicit_columns_resolve_ambiguity(tmp_path, colors255):
    # Coordinates that all lie in [0, 1] read like colours; only bin_columns tells the two layouts apart.
    rng = np.random.default_rng(10)
    unit_points = rng.random((N, 3))
    path = tmp_path / "unit.bin"
    unit_points.astype("<f4").tofile(path)
    _check(load_cloud(path, bin_columns=3), unit_points, None, atol=1e-6)
    assert len(load_cloud(path)) == N // 2  # the documented guess: the last three columns look like colours

    points6 = rng.uniform(-2, 2, size=(N, 3))
    path6 = tmp_path / "six.bin"
    np.hstack([points6, colors255]).astype("<f4").tofile(path6)
    _check(load_cloud(path6, bin_columns=6), points6, colors255 / 255.0, atol=1e-6)
    three = load_cloud(path6, bin_columns=3)
    assert len(three) == 2 * N and three.colors is None


def test_bin_columns_must_be_three_or_six(tmp_path, points):
    path = tmp_path / "scan.bin"
    points.astype("<f4").tofile(path)
    with pytest.raises(CloudError, match="3 .*or 6") as info:
        load_cloud(path, bin_columns=4)
    assert "scan.bin" in str(info.value)


# --- non-finite points --------------------------------------------------------------------------------------


def _poison(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points with NaN / inf in a few rows; returns the poisoned copy and the mask of good rows."""
    bad = points.copy()
    bad[3, 0] = np.nan
    bad[10, 2] = np.inf
    bad[11, 1] = -np.inf
    bad[N - 1] = np.nan
    good = np.isfinite(bad).all(axis=1)
    assert (~good).sum() == 4
    return bad, good


def _check_dropped(
    cloud: Cloud, points: np.ndarray, colors: np.ndarray | None, good: np.ndarray, atol: float
):
    assert cloud.dropped_nonfinite == 4
    assert len(cloud) == good.sum()
    assert any("4" in note and ("NaN" in note or "nan" in note) for note in cloud.notes), cloud.notes
    np.testing.assert_allclose(cloud.points, points[good], atol=atol, rtol=0)
    if colors is not None:
        # Each surviving point keeps its own colour.
        np.testing.assert_allclose(cloud.colors, colors[good], atol=0.5 / 255 + 1e-6, rtol=0)


def test_nonfinite_dropped_text(tmp_path, points, colors255):
    bad, good = _poison(points)
    path = tmp_path / "nan.xyz"
    _write_table(path, np.hstack([bad, colors255]))
    _check_dropped(load_cloud(path), points, colors255 / 255.0, good, 1e-9)


def test_nonfinite_dropped_npy(tmp_path, points, colors255):
    bad, good = _poison(points)
    path = tmp_path / "nan.npy"
    np.save(path, np.hstack([bad, colors255 / 255.0]))
    _check_dropped(load_cloud(path), points, colors255 / 255.0, good, 1e-9)


def test_nonfinite_dropped_bin(tmp_path, points, colors255):
    bad, good = _poison(points)
    path = tmp_path / "nan.bin"
    np.hstack([bad, colors255]).astype("<f4").tofile(path)
    cloud = load_cloud(path)  # auto-detection still sees colours in the last three columns
    _check_dropped(cloud, points, colors255 / 255.0, good, 1e-5)


@pytest.mark.parametrize("suffix", [".ply", ".pcd"])
def test_nonfinite_dropped_open3d_formats(tmp_path, points, colors255, suffix):
    import open3d as o3d

    bad, good = _poison(points)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(bad))
    pcd.colors = o3d.utility.Vector3dVector(colors255 / 255.0)
    path = tmp_path / f"nan{suffix}"
    assert o3d.io.write_point_cloud(str(path), pcd, write_ascii=False)
    _check_dropped(load_cloud(path), points, colors255 / 255.0, good, 1e-5)


# --- errors -------------------------------------------------------------------------------------------------


def _error(path: Path, match: str, **kwargs) -> CloudError:
    with pytest.raises(CloudError, match=match) as info:
        load_cloud(path, **kwargs)
    assert path.name in str(info.value), str(info.value)
    return info.value


def test_missing_file(tmp_path):
    _error(tmp_path / "nowhere.ply", "no such file")


def test_directory(tmp_path):
    folder = tmp_path / "looks_like_a_cloud.ply"
    folder.mkdir()
    _error(folder, "not a file")


def test_unknown_suffix_lists_supported_formats(tmp_path):
    path = tmp_path / "scan.las"
    path.write_bytes(b"LASF" + bytes(200))
    message = str(_error(path, "unknown cloud format"))
    assert "'.las'" in message
    for suffix in SUPPORTED_SUFFIXES:
        assert suffix in message


@pytest.mark.parametrize("suffix", SUPPORTED_SUFFIXES)
def test_empty_file(tmp_path, suffix):
    path = tmp_path / f"empty{suffix}"
    path.touch()
    _error(path, "empty file")


def test_unreadable_file(tmp_path, points, monkeypatch):
    """What a file without read permission gives (root may read any file, so the refusal is made here): the
    access check says no, or the check passes and the read itself is refused (a root-squashed share)."""
    path = tmp_path / "locked.xyz"
    _write_table(path, points)
    may_access = os.access

    def no_read(target, mode, *args, **kwargs):
        return False if Path(target) == path and mode & os.R_OK else may_access(target, mode, *args, **kwargs)

    with monkeypatch.context() as patched:
        patched.setattr(os, "access", no_read)
        _error(path, r"not readable \(permission denied\)")

    def refused(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "open", refused)
    _error(path, "cannot read as XYZ: .*Permission denied")


def test_ply_that_is_not_ply(tmp_path, points):
    path = tmp_path / "fake.ply"
    _write_table(path, points)  # an XYZ table with the wrong suffix
    _error(path, "not a PLY file")


def test_pcd_without_header(tmp_path, points):
    path = tmp_path / "headless.pcd"
    _write_table(path, points)
    _error(path, "no PCD header")


def test_pcd_truncated(tmp_path, points):
    import open3d as o3d

    full = tmp_path / "full.pcd"
    assert o3d.io.write_point_cloud(str(full), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)))
    path = tmp_path / "cut.pcd"
    data = full.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _error(path, "truncated")


def test_ply_binary_truncated(tmp_path, points):
    """Half a binary PLY: open3d fails to read it, and the loader must not hand back the unread vertices."""
    full = tmp_path / "full.ply"
    save_cloud(full, Cloud(points))
    path = tmp_path / "cut.ply"
    data = full.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _error(path, "cut.ply")


_ASCII_PLY_HEADER = (
    "ply\nformat ascii 1.0\nelement vertex 5\n"
    "property float x\nproperty float y\nproperty float z\nend_header\n"
)


@pytest.mark.parametrize(
    "body",
    ["1 2 3\n4 5 6\n", "1 2 3\n4 5 six\n7 8 9\n1 1 1\n2 2 2\n"],
    ids=["fewer-vertices-than-header", "non-numeric-vertex"],
)
def test_ply_ascii_unreadable_body(tmp_path, body):
    path = tmp_path / "broken.ply"
    path.write_text(_ASCII_PLY_HEADER + body)
    _error(path, "broken.ply")


@pytest.mark.parametrize("suffix", [".xyz", ".txt", ".pts"])
def test_text_not_numbers(tmp_path, suffix):
    path = tmp_path / f"words{suffix}"
    path.write_text("x y z\nhello there world\n1.0 2.0 oops\n")
    _error(path, "not a table of numbers")


def test_text_ragged_rows(tmp_path):
    path = tmp_path / "ragged.xyz"
    path.write_text("1 2 3\n4 5 6 7\n")
    _error(path, "not a table of numbers")


def test_text_wrong_column_count(tmp_path):
    path = tmp_path / "five.xyz"
    path.write_text("1 2 3 4 5\n6 7 8 9 10\n")
    _error(path, "got 5")


def test_text_only_comments(tmp_path):
    path = tmp_path / "comments.txt"
    path.write_text("# exported by nothing\n\n// still nothing\n")
    _error(path, "no points")


def test_bin_not_whole_points(tmp_path, points):
    path = tmp_path / "partial.bin"
    points[:5].astype("<f4").tofile(path)
    with path.open("ab") as handle:
        handle.write(np.float32(1.0).tobytes())  # 16 floats: neither 3 nor 6 per point
    message = str(_error(path, "not a whole number"))
    assert str(path.stat().st_size) in message


def test_bin_trailing_bytes(tmp_path, points):
    """A .bin cut inside a float is not a whole number of points either; the partial bytes must not vanish."""
    path = tmp_path / "cut.bin"
    data = points[:5].astype("<f4").tobytes()
    path.write_bytes(data + data[:2])  # 62 bytes
    _error(path, "not a whole number")


@pytest.mark.parametrize("shape", [(N,), (N, 4), (N, 3, 1), (N, 2)])
def test_npy_wrong_shape(tmp_path, shape):
    path = tmp_path / "odd.npy"
    np.save(path, np.zeros(shape))
    message = str(_error(path, r"expected an \(N, 3\) or \(N, 6\) array"))
    assert str(shape) in message


def test_npy_structured_without_xyz(tmp_path):
    path = tmp_path / "fields.npy"
    np.save(path, np.zeros(4, dtype=[("a", "f4"), ("b", "f4"), ("c", "f4")]))
    _error(path, "without x, y, z")


def test_npy_not_an_npy_file(tmp_path):
    path = tmp_path / "text.npy"
    path.write_text("1 2 3\n")
    _error(path, "NPY")


@pytest.mark.parametrize("suffix", [".npy", ".bin", ".xyz", ".ply"])
def test_all_points_nonfinite(tmp_path, suffix):
    table = np.full((8, 3), np.nan)
    table[::2, 1] = np.inf
    path = tmp_path / f"allnan{suffix}"
    if suffix == ".npy":
        np.save(path, table)
    elif suffix == ".bin":
        table.astype("<f4").tofile(path)
    elif suffix == ".xyz":
        _write_table(path, table)
    else:
        import open3d as o3d

        assert o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(table)))
    message = str(_error(path, "no points"))
    assert "8" in message  # says how many were dropped


def test_cloud_rejects_mismatched_colours():
    with pytest.raises(CloudError, match="colours"):
        Cloud(np.zeros((4, 3)), np.zeros((3, 3)))
    with pytest.raises(CloudError, match=r"\(N, 3\)"):
        Cloud(np.zeros((4, 2)))


def test_save_cloud_rejects_other_suffixes(tmp_path, points):
    with pytest.raises(CloudError, match="out.xyz"):
        save_cloud(tmp_path / "out.xyz", Cloud(points))
