"""The demo's recording as a person first sees it: the real Rerun viewer (headless, benchmarks/
recording_screenshots.py) renders its first view, which must not be blank and must show each affordance's
colour in 3D and, on the plan, where the map's JSON puts its places. Skips only when the viewer cannot run
here (no Xvfb or Vulkan driver: `bash bootstrap.sh test` installs them as root)."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

from affordcore.mapping.plots import CEILING_CUT
from affordcore.mapping.recording import PLAN_CELL
from benchmarks.recording_screenshots import (
    WINDOW,
    ViewerUnavailable,
    demo_recording,
    headless_display,
    screenshot,
)

pytestmark = pytest.mark.slow
AFFORDANCES = ("sitting-relaxing", "sitting-working", "standing-working")  # the demo's, in class order
FLOOR_GREY = (233, 236)  # how the plan draws a cell whose highest point is on the floor (235), as rendered


def _near(image: np.ndarray, color: np.ndarray, tolerance: float = 40.0) -> np.ndarray:
    return np.linalg.norm(image - color, axis=-1) < tolerance


def _floor_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (x, y) corners of the plan's floor cells (highest point within 1 cm of the floor), from the cloud
    itself: which part of the screenshot's plan is which part of the room."""
    from affordcore.mapping.plots import plan_heights

    top, corner = plan_heights(points[points[:, 2] <= CEILING_CUT], PLAN_CELL)
    cells = np.argwhere(top < 0.01)
    return corner + cells.min(axis=0) * PLAN_CELL, corner + (cells.max(axis=0) + 1) * PLAN_CELL


def _first_view(rrd, out) -> tuple[np.ndarray, float, np.ndarray]:
    """The viewer's first view of the recording `rrd` (skips when the viewer cannot run here): the image
    (float RGB), its pixels per window point, and its 3D view (the left 3/5 below the tab bar)."""
    from PIL import Image

    try:
        with headless_display() as display:
            shot = screenshot([rrd], out, display)
    except ViewerUnavailable as error:
        pytest.skip(str(error))
    image = np.asarray(Image.open(shot).convert("RGB")).astype(float)
    scale = image.shape[1] / WINDOW[0]
    return image, scale, image[int(80 * scale) :, : int(0.58 * image.shape[1])]


def test_the_demo_recording_opens_on_each_affordances_places(tmp_path):
    from affordcore.geometry.scene import load_cloud

    image, scale, view = _first_view(demo_recording(tmp_path / "demo"), tmp_path / "demo.png")
    colors = np.array([matplotlib.colormaps["tab10"](i)[:3] for i in range(3)]) * 255
    maps = {name: json.loads((tmp_path / "demo" / f"{name}.json").read_text()) for name in AFFORDANCES}

    # the 3D view is not blank: the room's points fill much of it, and each affordance's skeletons show in
    # its colour
    assert (view.max(axis=-1) > 60).mean() > 0.2
    for name, color in zip(AFFORDANCES, colors):
        assert _near(view, color).sum() > 200 * scale**2, f"{name}'s colour is not in the 3D view"

    # the plan (top right): its floor cells are the cloud's, so their box on screen maps the room to pixels
    plan = image[int(80 * scale) : int(0.6 * image.shape[0]), int(0.62 * image.shape[1]) :]
    floor = np.all((plan >= FLOOR_GREY[0]) & (plan <= FLOOR_GREY[1]), axis=-1)
    # the rows and columns the floor crosses for more than a few pixels (not the light grey of UI text)
    rows, columns = np.nonzero(floor.sum(axis=1) > 20)[0], np.nonzero(floor.sum(axis=0) > 20)[0]
    world_from_input = np.array(maps[AFFORDANCES[0]]["world_from_input"])
    points = load_cloud(tmp_path / "demo" / "example-room.ply").points
    low, high = _floor_box(points @ world_from_input[:3, :3].T + world_from_input[:3, 3])
    pixels_per_metre = (columns.max() - columns.min()) / (high[0] - low[0])
    assert pixels_per_metre == pytest.approx((rows.max() - rows.min()) / (high[1] - low[1]), rel=0.05)
    found = 0
    for name, color in zip(AFFORDANCES, colors):
        for place in maps[name]["skeletons"]:
            column = columns.min() + (place["x"] - low[0]) * pixels_per_metre
            row = rows.min() + (high[1] - place["y"]) * pixels_per_metre  # the plan's y runs up the screen
            reach = int(0.3 * pixels_per_metre)
            around = plan[int(row) - reach : int(row) + reach, int(column) - reach : int(column) + reach]
            assert _near(around, color).sum() > 10, f"{name}'s place at ({place['x']}, {place['y']})"
            found += 1
    assert found == sum(len(m["skeletons"]) for m in maps.values()) and found >= 3


def test_a_recording_of_a_run_opens_at_its_last_map_not_at_its_first_scan(tmp_path):
    """A service run's recording is timed (each scan and map at its stamp); opened afterwards, its first view
    is its latest time, with the final map, and not the run's start, where the room is still empty (played
    from the start, a screenshot of a service run showed an empty viewer)."""
    from affordcore.geometry.grid import PoseGrid
    from affordcore.geometry.skeleton import get_skeleton
    from affordcore.mapping.maps import build_map
    from affordcore.mapping.recording import close_recording, log_cloud, log_map, open_recording, set_time

    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(0, 3, (4000, 2)), np.zeros(4000)])
    grid = PoseGrid(
        np.arange(30) * 0.1 + 0.05, np.arange(30) * 0.1 + 0.05, np.array([0.5]), np.arange(4) * 1.5
    )
    scores = np.full(grid.shape, -3.0, np.float32)
    scores[0, 1, 15, 15] = 2.0  # one place, in the room's middle
    amap = build_map(AFFORDANCES[0], scores, grid, get_skeleton(AFFORDANCES[0]), threshold=0.1)
    rrd = tmp_path / "run.rrd"
    recording = open_recording(rrd, [AFFORDANCES[0]], name="a run")
    set_time(recording, 1_700_000_000.0)
    log_cloud(recording, floor[:50])  # the first scan's few points
    set_time(recording, 1_700_000_120.0)  # two minutes on: the room and its map
    log_cloud(recording, floor)
    log_map(recording, amap)
    close_recording(recording)
    _, scale, view = _first_view(rrd, tmp_path / "run.png")
    blue = np.array(matplotlib.colormaps["tab10"](0)[:3]) * 255
    assert _near(view, blue).sum() > 100 * scale**2, "the last map's skeleton is not in the first view"
