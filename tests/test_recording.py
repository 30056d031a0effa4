"""The Rerun recording as its users read it: skeletons as keypoints of an AnnotationContext (joint names,
bones, a class and colour per affordance, the names hidden until hovered), confidence as scalar values with
a colour bar and its range, the places as a table, the plan view, static data static and a named recording.

Every test writes a recording through the real logging functions and reads the .rrd back."""

from __future__ import annotations

import dataclasses

import matplotlib
import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import BONE_ENDS, JOINTS, get_skeleton
from affordcore.mapping.maps import build_map
from affordcore.mapping.plots import CEILING_CUT
from affordcore.mapping.recording import (
    LEGEND_STEPS,
    affordance_colors,
    close_recording,
    confidence_colors,
    log_cloud,
    log_map,
    log_trajectory,
    open_recording,
    recorded_entities,
    set_time,
)


def _map(affordance: str, places: list[tuple[int, int, float]], skeleton: str = "sitting-relaxing"):
    """A small map with one skeleton per (ix, iy, score) place (they are far apart: no suppression)."""
    grid = PoseGrid(
        np.arange(30) * 0.1 + 0.05, np.arange(12) * 0.1 - 0.55, np.array([0.5, 0.6]), np.arange(4) * 1.5
    )
    scores = np.full(grid.shape, -3.0, dtype=np.float32)
    scores[0, 0, 29, 0] = -0.5  # below the threshold: no cell, no skeleton
    for ix, iy, score in places:
        scores[1, 2, ix, iy] = score
        scores[0, 1, ix, iy + 1] = score / 4  # a weaker neighbour: a cell above the threshold, no place
    return build_map(affordance, scores, grid, get_skeleton(skeleton), threshold=0.1)


def _rows(path, entity: str) -> list[dict]:
    """Every logged row of one entity, in log order: its components (Archetype:field -> value), whether it is
    static and its `stamp` (ns, None when static)."""
    rows = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path != entity or chunk.is_empty:
            continue
        batch = chunk.to_record_batch()
        stamps = batch.column("stamp").cast(pa.int64()) if "stamp" in batch.schema.names else None
        for i in range(batch.num_rows):
            row = {
                name: column[i].as_py()
                for name, column in zip(batch.schema.names, batch.columns)
                if ":" in name and column[i].is_valid
            }
            row["static"], row["stamp"] = chunk.is_static, stamps[i].as_py() if stamps is not None else None
            rows.append(row)
    return rows


def _last(path, entity: str, component: str):
    values = [row[component] for row in _rows(path, entity) if component in row]
    assert values, f"{entity} has no {component}"
    return values[-1]


@pytest.fixture
def recorded(tmp_path):
    """Two affordances the recording was opened with and one it was not (a user's skeleton file)."""
    relaxing = _map("sitting-relaxing", [(5, 3, 2.0), (20, 8, 1.0)])
    working = _map("standing-working", [(12, 5, 1.5)], "standing-working")
    extra = _map("lying-down", [(25, 2, 0.7)])
    path = tmp_path / "map.rrd"
    recording = open_recording(path, ["sitting-relaxing", "standing-working"])
    set_time(recording, 10.0)
    for amap in (relaxing, working, extra):
        log_map(recording, amap)
    assert close_recording(recording) is None
    return path, {amap.affordance: amap for amap in (relaxing, working, extra)}


def test_the_annotation_context_names_the_joints_connects_the_bones_and_has_a_class_per_affordance(recorded):
    path, _ = recorded
    contexts = [row for row in _rows(path, "/world") if "AnnotationContext:context" in row]
    assert contexts and all(row["static"] for row in contexts)
    classes = contexts[-1]["AnnotationContext:context"][0]  # the last static write is what the viewer uses
    # class ids in the order the recording was opened with, the affordance it did not know appended
    assert [(c["class_id"], c["class_description"]["info"]["label"]) for c in classes] == [
        (1, "sitting-relaxing"),
        (2, "standing-working"),
        (3, "lying-down"),
    ]
    colors = [c["class_description"]["info"]["color"] for c in classes]
    assert None not in colors and len(set(colors)) == 3
    for entry in classes:
        description = entry["class_description"]
        assert description["info"]["id"] == entry["class_id"]
        assert [(k["id"], k["label"]) for k in description["keypoint_annotations"]] == list(enumerate(JOINTS))
        connections = {(c["keypoint0"], c["keypoint1"]) for c in description["keypoint_connections"]}
        assert connections == {tuple(pair) for pair in BONE_ENDS.tolist()} and len(connections) == 15
        named = {(JOINTS[a], JOINTS[b]) for a, b in connections}
        assert ("HEAD", "NECK") in named and ("L_KNEE", "L_FOOT") in named


def test_each_skeleton_is_one_entity_of_keypoints_with_its_affordance_class(recorded):
    path, maps = recorded
    entities = recorded_entities(path)
    for class_id, (affordance, amap) in enumerate(maps.items(), start=1):
        assert len(amap.joints) == {"sitting-relaxing": 2, "standing-working": 1, "lying-down": 1}[affordance]
        for rank, joints in enumerate(amap.joints):
            entity = f"/world/{affordance}/skeletons/{rank}"
            assert _last(path, entity, "Points3D:class_ids") == [class_id]
            assert _last(path, entity, "Points3D:keypoint_ids") == list(range(15))
            assert _last(path, entity, "Points3D:show_labels") == [False]  # joint names only on hover
            np.testing.assert_allclose(_last(path, entity, "Points3D:positions"), joints, atol=1e-5)
        assert f"/world/{affordance}/skeletons/{len(amap.joints)}" not in entities
        # the skeleton map's summary and the places, in the affordance's colour (its class)
        assert _last(path, f"/world/{affordance}/skeletons", "affordmap.SkeletonMap:count") == [
            len(amap.joints)
        ]
        assert _last(path, f"/world/{affordance}/places", "Points3D:class_ids") == [class_id]
        np.testing.assert_allclose(
            _last(path, f"/world/{affordance}/places", "Points3D:positions"),
            amap.joints[:, JOINTS.index("TORSO")],
            atol=1e-5,
        )
    # the two skeletons of one map are not the same pose
    first, second = (
        np.array(_last(path, f"/world/sitting-relaxing/skeletons/{rank}", "Points3D:positions"))
        for rank in (0, 1)
    )
    assert np.linalg.norm(first - second, axis=1).min() > 1.0


def test_a_map_with_fewer_skeletons_clears_the_ones_it_no_longer_has(tmp_path):
    path = tmp_path / "map.rrd"
    recording = open_recording(path, ["sitting-relaxing"])
    set_time(recording, 1.0)
    log_map(recording, _map("sitting-relaxing", [(5, 3, 2.0), (20, 8, 1.0), (12, 1, 0.5)]))
    set_time(recording, 2.0)
    log_map(recording, _map("sitting-relaxing", [(7, 7, 1.0)]))
    close_recording(recording)
    for rank, cleared in ((0, False), (1, True), (2, True)):
        rows = _rows(path, f"/world/sitting-relaxing/skeletons/{rank}")
        at_two = [row for row in rows if row["stamp"] == 2_000_000_000]
        assert len(at_two) == 1, rows
        if cleared:
            assert at_two[0]["Clear:is_recursive"] == [False] and "Points3D:positions" not in at_two[0]
        else:
            assert at_two[0]["Points3D:keypoint_ids"] == list(range(15))
    assert _last(path, "/world/sitting-relaxing/skeletons", "affordmap.SkeletonMap:count") == [1]


def test_confidence_is_the_scalar_value_with_its_colormap_and_range(recorded):
    path, maps = recorded
    amap = maps["sitting-relaxing"]
    entity = "/world/sitting-relaxing/confidence"
    ix, iy = np.nonzero(amap.confidence > amap.threshold)
    values = np.array(_last(path, entity, "affordmap.Confidence:value"))
    np.testing.assert_allclose(values, amap.confidence[ix, iy], rtol=1e-6)
    assert len(values) == 4 and values.max() == pytest.approx(2.0)  # two places and their weaker neighbours
    low, high = _last(path, entity, "affordmap.Confidence:value_range")[0]
    assert (low, high) == pytest.approx((amap.threshold, 2.0))
    # the colours run from a pale tint of the affordance's colour (the threshold) to that colour (the best)
    packed = np.array(_last(path, entity, "Points3D:colors"), dtype=np.uint32)
    rgb = np.column_stack([(packed >> shift) & 0xFF for shift in (24, 16, 8)]).astype(float)
    blue = np.array(matplotlib.colormaps["tab10"](0)[:3]) * 255  # sitting-relaxing: the first class
    np.testing.assert_allclose(rgb[values.argmax()], blue, atol=1)
    t = (values - low) / (high - low)
    pale = 0.25 * blue + 0.75 * 255
    np.testing.assert_allclose(rgb, pale + t[:, None] * (blue - pale), atol=1)
    assert len({tuple(c) for c in rgb}) == len(set(values))  # one colour per value
    # the plan shows the same map as an image: its opaque pixels are the cells above the threshold
    image = _last(path, "/plan/sitting-relaxing/confidence", "Image:buffer")
    assert int(np.count_nonzero(np.array(image[0], dtype=np.uint8).reshape(-1, 4)[:, 3])) == 4
    # each affordance's colour bar is named with its range, in a row of its own below the plan
    label = _last(path, "/plan/sitting-relaxing/legend/range", "Points2D:labels")
    assert label == [f"sitting-relaxing: {low:.2f} (pale) to {high:.2f}"]
    rows = {_last(path, f"/plan/{name}/legend/range", "Points2D:positions")[0][1] for name in maps}
    assert len(rows) == 3


def test_each_colour_bar_is_centred_under_the_plan_with_its_label_below_it_clear_of_the_next(recorded):
    """A point's label is drawn centred under the point: each label's point is at its bar's middle, just
    below the bar, with room before the next row; and no transform above the label (the bar's image
    transform once scaled the labels into the bar's left end)."""
    path, maps = recorded
    rows = []
    for name, amap in maps.items():  # in class order
        (u0, v0, _), (su, sv, _) = (
            _last(path, f"/plan/{name}/legend/bar", f"Transform3D:{field}")[0]
            for field in ("translation", "scale")
        )
        bar = (u0, u0 + LEGEND_STEPS * su, v0, v0 + 2 * sv)  # 64 steps, two rows of pixels; v down the screen
        ((u, v),) = _last(path, f"/plan/{name}/legend/range", "Points2D:positions")
        for entity in ("/plan", f"/plan/{name}", f"/plan/{name}/legend", f"/plan/{name}/legend/range"):
            assert not any(key.startswith("Transform3D:") for row in _rows(path, entity) for key in row), (
                entity
            )
        grid = amap.grid
        assert (bar[0] + bar[1]) / 2 == pytest.approx(
            (grid.x[0] + grid.x[-1]) / 2, abs=1e-4
        )  # under the plan
        assert bar[2] > -grid.y[0]  # below the floor (the plan's v is -y)
        assert u == pytest.approx((bar[0] + bar[1]) / 2, abs=1e-4)
        assert v > bar[3]  # the label hangs below its point, so below the bar
        rows.append((bar, v))
    for (_, label_v), (next_bar, _) in zip(rows, rows[1:]):
        assert next_bar[2] - label_v >= 0.3  # metres for the label's line before the next bar


def test_the_trajectory_is_drawn_in_a_colour_no_affordance_uses(tmp_path):
    path = tmp_path / "assembler.rrd"
    recording = open_recording(path, ["sitting-relaxing"])
    set_time(recording, 1.0)
    log_trajectory(recording, np.array([[0.0, 0.0, 1.2], [0.5, 0.1, 1.2], [1.0, 0.3, 1.3]]), np.eye(4))
    close_recording(recording)
    (packed,) = _last(path, "/world/odom/trajectory", "LineStrips3D:colors")
    rgb = tuple(int(packed >> shift) & 0xFF for shift in (24, 16, 8))
    assert rgb[0] == rgb[1] == rgb[2] >= 200, rgb  # light and neutral: no hue to mistake for a map's
    colours = affordance_colors([f"affordance-{i}" for i in range(10)])
    bars = [confidence_colors(np.array([0.0, 0.5, 1.0]), 0.0, 1.0, colour) for colour in colours]
    assert rgb not in {tuple(int(c) for c in colour) for colour in [*colours, *np.vstack(bars)]}


def test_the_places_table_lists_every_place_with_its_probability_or_says_none_was_found(recorded, tmp_path):
    path, maps = recorded
    (text,) = _last(path, "/places", "TextDocument:text")
    rows = [line.split("|")[1:-1] for line in text.splitlines()[2:]]
    # these maps have no place model: their places read as scores (a shipped model's as probabilities,
    # tests/test_map.py)
    assert all(np.isnan(amap.probabilities).all() for amap in maps.values())
    expected = [
        (f"{name} ({colour})", str(rank + 1), f"score {score:.2f}")
        for (name, amap), colour in zip(maps.items(), ("blue", "orange", "green"))
        for rank, score in enumerate(amap.skeletons[:, 4])
    ]
    assert expected[0][2] == "score 2.00" and len(expected) == 4
    assert [tuple(cell.strip() for cell in row[:3]) for row in rows] == expected
    # an affordance without a place says so; one not mapped yet too
    path = tmp_path / "empty.rrd"
    recording = open_recording(path, ["sitting-relaxing", "standing-working"])
    log_map(recording, _map("standing-working", [], "standing-working"))
    close_recording(recording)
    (text,) = _last(path, "/places", "TextDocument:text")
    assert "| sitting-relaxing | not mapped yet |" in text
    assert "| standing-working (orange) | **no place found** |" in text
    assert "more with" not in text
    # a map that left places under its probability says how many, under the table
    path = tmp_path / "unsure.rrd"
    recording = open_recording(path, ["sitting-relaxing"])
    log_map(recording, dataclasses.replace(_map("sitting-relaxing", [(5, 3, 2.0)]), unsure_places=2))
    close_recording(recording)
    (text,) = _last(path, "/places", "TextDocument:text")
    assert text.endswith("|\n\n* sitting-relaxing: 2 more with AFFORD_MAP__PLACE_PROBABILITY=0.1\n"), text


def test_an_empty_map_records_an_empty_skeleton_map_and_a_valid_range(tmp_path):
    path = tmp_path / "map.rrd"
    recording = open_recording(path, ["standing-working"])
    log_map(recording, _map("standing-working", [], "standing-working"))
    close_recording(recording)
    assert _last(path, "/world/standing-working/skeletons", "affordmap.SkeletonMap:count") == [0]
    assert _last(path, "/world/standing-working/confidence", "affordmap.Confidence:value") == []
    # no cell above the threshold: the range is the threshold and one above it
    (range_,) = _last(path, "/world/standing-working/confidence", "affordmap.Confidence:value_range")
    assert range_ == pytest.approx([0.1, 1.1])
    assert not any("/skeletons/" in entity for entity in recorded_entities(path))


def test_affordance_colours_are_distinct_and_the_same_for_the_same_list():
    names = [f"affordance-{i}" for i in range(12)]
    colors = affordance_colors(names)
    assert colors.shape == (12, 3) and colors.dtype == np.uint8
    assert len({tuple(c) for c in colors[:10]}) == 10
    np.testing.assert_array_equal(affordance_colors(names), colors)
    np.testing.assert_array_equal(
        affordance_colors(names[:3]), colors[:3]
    )  # by order, not by the list's length
    assert affordance_colors([]).shape == (0, 3)


def test_an_offline_recording_is_static_named_and_keeps_the_ceiling_out_of_the_first_view(tmp_path):

    path = tmp_path / "map.rrd"
    recording = open_recording(path, ["sitting-relaxing"], name="example-room map 2026-01-02 03:04:05")
    floor = np.column_stack([np.random.default_rng(0).uniform(0, 3, (500, 2)), np.zeros(500)])
    ceiling = floor + [0.0, 0.0, 2.6]
    log_cloud(recording, np.vstack([floor, ceiling]))
    log_map(recording, _map("sitting-relaxing", [(5, 3, 2.0)]))
    close_recording(recording)
    # no time was set: everything is static (no log_time or log_tick stamps)
    rows = [row for entity in recorded_entities(path) for row in _rows(path, entity)]
    assert rows and all(row["static"] for row in rows)
    assert all(
        set(chunk.to_record_batch().schema.names).isdisjoint({"log_time", "log_tick"})
        for chunk in RrdReader(str(path)).stream().to_chunks()
    )
    # the points above CEILING_CUT have an entity of their own (which the first view leaves out)
    below = np.array(_last(path, "/world/cloud", "Points3D:positions"))
    above = np.array(_last(path, "/world/cloud/above", "Points3D:positions"))
    assert (len(below), len(above)) == (500, 500)
    assert below[:, 2].max() <= CEILING_CUT < above[:, 2].min()
    # the recording's id is its name: a person recognises it in the viewer
    ids = {(r.application_id, r.recording_id) for r in RrdReader(str(path)).recordings()}
    assert ("affordmap", "example-room map 2026-01-02 03:04:05") in ids


def _eyes(path) -> list[list[float]]:
    """The look target of the 3D eye of every blueprint the recording sent with one (the file's stores come in
    no particular order)."""
    reader, targets = RrdReader(str(path)), []
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            batch = chunk.to_record_batch()
            if "EyeControls3D:look_target" in batch.schema.names:
                targets.append(batch.column("EyeControls3D:look_target").to_pylist()[-1][0])
    return targets


def test_the_view_is_framed_anew_when_a_robots_room_grows_beyond_it_and_not_for_every_map(tmp_path):
    """A live robot's first map is of a corner of its room: a view framed on it alone shows the final room
    cut off and from too close (docs/figures/recording-services.png once opened that way)."""

    def floor_map(x_end: float, y_end: float):
        grid = PoseGrid(
            np.arange(0.05, x_end, 0.1), np.arange(0.05, y_end, 0.1), np.array([0.5]), np.zeros(1)
        )
        return build_map(
            "sitting-relaxing",
            np.full(grid.shape, -3.0, np.float32),
            grid,
            get_skeleton("sitting-relaxing"),
            threshold=0.1,
        )

    path = tmp_path / "live.rrd"
    recording = open_recording(path, ["sitting-relaxing"])
    for stamp, (x_end, y_end) in enumerate([(1.0, 1.0), (1.3, 1.2), (4.0, 3.0), (4.2, 3.1)]):
        set_time(recording, float(stamp))
        log_map(recording, floor_map(x_end, y_end))
    close_recording(recording)
    eyes = sorted(np.round(target[:2], 6).tolist() for target in _eyes(path))
    # framed at the first map (on its middle) and once the floor reached 3 m beyond it (on the grown floor's);
    # not for the maps within half a metre of the floor framed
    assert eyes == [[0.5, 0.5], [2.0, 1.5]]
