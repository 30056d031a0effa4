"""Label files, per-pose ground truth, place matching and the label plot (affordcore.labels)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from affordcore.geometry.grid import PoseGrid
from affordcore.labels import (
    THETA_TOLERANCE,
    XY_TOLERANCE,
    ClassCount,
    Label,
    LabelError,
    LabelSet,
    UnlabelledRegion,
    affordance_colours,
    class_counts,
    ground_truth,
    load_labels,
    match_places,
    save_labels,
)
from affordcore.mapping.plots import plot_labels

TWO_PI = 2 * math.pi


def room(*labels: Label, regions: tuple[UnlabelledRegion, ...] = ()) -> LabelSet:
    return LabelSet("test room", "room.ply", "z-up, metres, floor at z = 0", labels, regions)


def grid(x, y, theta=(0.0,), z=(1.0,)) -> PoseGrid:
    return PoseGrid(x=np.array(x), y=np.array(y), z=np.array(z), theta=np.array(theta))


def positives(labels: LabelSet, g: PoseGrid, affordance: str = "perch") -> np.ndarray:
    return ground_truth(labels, affordance, g).positive


# ------------------------------------------------------------------------------------ tolerances


def test_tolerances_are_the_design_values():
    assert (XY_TOLERANCE, THETA_TOLERANCE) == (0.15, 0.4)


@pytest.mark.parametrize(
    "label",
    [
        Label("perch", 0.0, start=(-1.0, 0.0), end=(1.0, 0.0)),
        Label("perch", 0.0, at=(0.0, 0.0)),
    ],
)
def test_xy_tolerance_edge(label):
    truth = positives(room(label), grid([0.0], [0.149, 0.151]))
    assert truth[0, 0].tolist() == [True, False]
    truth = positives(room(label), grid([0.0], [-0.151, -0.149]))
    assert truth[0, 0].tolist() == [False, True]


def test_segment_end_caps_measure_to_the_nearest_end():
    sofa = room(Label("perch", 0.0, start=(0.0, 0.0), end=(1.0, 0.0)))
    assert positives(sofa, grid([1.149, 1.151], [0.0]))[0, :, 0].tolist() == [True, False]
    assert positives(sofa, grid([-0.151, -0.149], [0.0]))[0, :, 0].tolist() == [False, True]
    # off the end diagonally: 0.10 and 0.12 m from the line, but 0.141 and 0.156 m from the end point
    assert positives(sofa, grid([1.1], [0.10, 0.12]))[0, 0].tolist() == [True, False]


def test_segment_covers_its_length_and_a_point_only_its_disc():
    segment = room(Label("perch", 0.0, start=(0.0, 0.0), end=(1.0, 0.0)))
    point = room(Label("perch", 0.0, at=(0.0, 0.0)))
    g = grid([0.0, 0.5, 1.0], [0.1])
    assert positives(segment, g)[0, :, 0].tolist() == [True, True, True]
    assert positives(point, g)[0, :, 0].tolist() == [True, False, False]
    degenerate = room(Label("perch", 0.0, start=(0.0, 0.0), end=(0.0, 0.0)))  # zero length: a point
    assert positives(degenerate, g).tolist() == positives(point, g).tolist()


@pytest.mark.parametrize(
    "facing, thetas, expected",
    [
        (1.0, [1.39, 1.41, 0.61, 0.59], [True, False, True, False]),
        # across the 0 / 2 pi wrap, both ways
        (
            6.25,
            [0.05, 6.25 + 0.39 - TWO_PI, 6.25 + 0.41 - TWO_PI, 5.86, 5.84],
            [True, True, False, True, False],
        ),
        (
            0.05,
            [6.25, 0.05 - 0.39 + TWO_PI, 0.05 - 0.41 + TWO_PI, 0.44, 0.46],
            [True, True, False, True, False],
        ),
        # facing outside [0, 2 pi) (files may say -1.5708)
        (-0.03, [6.2, 0.36, 0.38, 3.14], [True, True, False, False]),
    ],
)
def test_theta_tolerance_edge_and_wrap(facing, thetas, expected):
    truth = positives(room(Label("perch", facing, at=(0.0, 0.0))), grid([0.0], [0.0], theta=thetas))
    assert truth[:, 0, 0].tolist() == expected


def test_every_z_level_counts_and_other_affordances_are_ignored():
    labels = room(Label("perch", 0.0, at=(0.0, 0.0)), Label("lean", 0.0, at=(5.0, 5.0)))
    truth = ground_truth(labels, "perch", grid([0.0, 0.1], [0.0], theta=[0.0, 1.0], z=[0.5, 0.6, 0.7]))
    mask = truth.pose_mask()
    assert mask.shape == (3, 2, 2, 1)
    assert all((mask[k] == truth.positive).all() for k in range(3))
    assert mask.sum() == 3 * 2  # (x 0.0 and 0.1, theta 0) at every z
    assert ground_truth(labels, "unknown type", truth.grid).counts() == (0, 12)


def test_unlabelled_regions_exclude_poses_whatever_their_theta():
    square = UnlabelledRegion(((0.05, -1.0), (1.0, -1.0), (1.0, 1.0), (0.05, 1.0)), "not scanned")
    labels = room(Label("perch", 0.0, start=(0.0, 0.0), end=(0.3, 0.0)), regions=(square,))
    g = grid([0.0, 0.1, 0.2], [0.0], theta=[0.0, 3.0], z=[0.5, 0.6])
    truth = ground_truth(labels, "perch", g)
    assert truth.excluded[:, 0].tolist() == [False, True, True]
    assert truth.positive[:, :, 0].tolist() == [[True, False, False], [False, False, False]]
    scored = truth.scored_mask()
    assert scored.shape == g.shape and not scored[:, :, 1:].any() and scored[:, :, 0].all()
    assert truth.counts() == (2, 2)  # x = 0: theta 0 positive, theta 3 negative, at 2 z levels


def test_counts_on_a_hand_computed_grid():
    labels = room(
        Label("perch", 0.0, at=(0.05, 0.05)),
        Label("lean", 0.0, at=(0.05, 0.05)),
        regions=(UnlabelledRegion(((0.3, 0.0), (0.4, 0.0), (0.4, 0.3), (0.3, 0.3))),),
    )
    # 4 x 3 cells; within 0.15 m of (0.05, 0.05): (0.05, 0.05), (0.15, 0.05), (0.05, 0.15), (0.15, 0.15)
    g = grid([0.05, 0.15, 0.25, 0.35], [0.05, 0.15, 0.25], theta=[0.0, 1.0, 2.0, 3.0], z=[0.5, 0.6])
    truth = ground_truth(labels, "perch", g)
    assert truth.positive[0].sum() == 4 and not truth.positive[1:].any()
    assert truth.excluded.sum() == 3  # the x = 0.35 column
    positive, negative = truth.counts()
    assert (positive, negative) == (4 * 2, 9 * 4 * 2 - 8)
    negatives = truth.scored_mask() & ~truth.pose_mask()
    assert (positive, negative) == (int(truth.pose_mask().sum()), int(negatives.sum()))
    assert class_counts(labels, {"perch": g, "lean": g}) == {
        "lean": ClassCount(8, 64, "1:8"),
        "perch": ClassCount(8, 64, "1:8"),
    }


def test_class_count_ratio_reads_like_the_paper():
    assert ClassCount.of(2457, 1285326).ratio == "1:523"
    assert ClassCount.of(213, 2570439).ratio == "1:12,067"
    assert ClassCount.of(0, 10).ratio == "no positives"


# ------------------------------------------------------------------------------------------ file I/O


def full_room() -> LabelSet:
    return room(
        Label("perch", -1.5708, start=(1.2, 3.0), end=(2.6, 3.0), note="3-seat sofa"),
        Label("lean", 0.0, at=(4.1, 0.8)),
        Label("levitating", 0.1, at=(0, 0), note="an affordance with no skeleton loads too"),
        regions=(
            UnlabelledRegion(((0, 0), (1, 0), (1, 1), (0, 1)), "not scanned"),
            UnlabelledRegion(((5, 5), (6, 5), (6, 6))),
        ),
    )


def test_save_load_round_trip(tmp_path):
    labels = full_room()
    path = save_labels(tmp_path / "room.labels.json", labels)
    assert load_labels(path) == labels
    document = json.loads(path.read_text())
    assert document["format"] == "affordance-labels/1"
    assert document["labels"][0] == {
        "affordance": "perch",
        "from": [1.2, 3.0],
        "to": [2.6, 3.0],
        "facing": -1.5708,
        "note": "3-seat sofa",
    }
    assert document["labels"][1] == {"affordance": "lean", "at": [4.1, 0.8], "facing": 0.0}
    assert set(document) == {"format", "scene", "cloud", "frame", "labels", "unlabelled_regions"}


def test_save_refuses_what_load_would_refuse(tmp_path):
    with pytest.raises(LabelError, match=r"bad\.labels\.json: labels\[0\]\.facing must be finite"):
        save_labels(tmp_path / "bad.labels.json", room(Label("perch", float("nan"), at=(0, 0))))
    assert not (tmp_path / "bad.labels.json").exists()
    with pytest.raises(ValueError):
        Label("perch", 0.0, at=(0, 0), start=(0, 0), end=(1, 0))


def edit(document: dict, change) -> dict:
    change(document)
    return document


@pytest.mark.parametrize(
    "change, field, problem",
    [
        (lambda d: d.update(format="affordance-labels/2"), "format", "must be 'affordance-labels/1'"),
        (lambda d: d.pop("format"), "format", "must be"),
        (lambda d: d.pop("scene"), "scene", "is missing"),
        (lambda d: d.update(cloud=3), "cloud", "must be a string"),
        (lambda d: d.update(labels={"0": {}}), "labels", "must be a list"),
        (lambda d: d.update(unlabeled_regions=[]), "unlabeled_regions", "is not a field"),
        (lambda d: d["labels"][1].update({"from": [0, 0], "to": [1, 0]}), "labels[1]", "not both"),
        (lambda d: d["labels"][1].pop("at"), "labels[1]", "either 'at'"),
        (lambda d: d["labels"][0].pop("to"), "labels[0].to", "is missing"),
        (lambda d: d["labels"][1].update(at=[1.0]), "labels[1].at", "must be 2 numbers"),
        (lambda d: d["labels"][1].update(at=[1.0, 2.0, 3.0]), "labels[1].at", "must be 2 numbers"),
        (lambda d: d["labels"][0].update({"from": ["1.2", 3.0]}), "labels[0].from[0]", "must be a number"),
        (lambda d: d["labels"][0].update(to=[2.6, float("inf")]), "labels[0].to[1]", "must be finite"),
        (lambda d: d["labels"][2].update(facing="north"), "labels[2].facing", "must be a number"),
        (lambda d: d["labels"][2].update(facing=True), "labels[2].facing", "must be a number"),
        (lambda d: d["labels"][2].update(facing=float("nan")), "labels[2].facing", "must be finite"),
        (lambda d: d["labels"][2].pop("facing"), "labels[2].facing", "is missing"),
        (lambda d: d["labels"][1].update(affordance=""), "labels[1].affordance", "non-empty string"),
        (lambda d: d["labels"][1].update(facng=0.0), "labels[1].facng", "is not a field"),
        (lambda d: d["labels"].append("sofa"), "labels[3]", "must be an object"),
        (
            lambda d: d["unlabelled_regions"][1].update(polygon=[[0, 0], [1, 1]]),
            "unlabelled_regions[1].polygon",
            "at least 3 vertices",
        ),
        (
            lambda d: d["unlabelled_regions"][0]["polygon"].__setitem__(2, [1, None]),
            "unlabelled_regions[0].polygon[2][1]",
            "must be a number",
        ),
    ],
)
def test_validation_errors_name_the_file_and_the_field(tmp_path, change, field, problem):
    path = tmp_path / "room.labels.json"
    document = edit(json.loads(save_labels(path, full_room()).read_text()), change)
    path.write_text(json.dumps(document))
    with pytest.raises(LabelError) as error:
        load_labels(path)
    assert str(error.value).startswith(f"{path}: {field} "), str(error.value)
    assert problem in str(error.value)


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(LabelError, match=r"missing\.labels\.json: cannot read"):
        load_labels(tmp_path / "missing.labels.json")
    broken = tmp_path / "broken.labels.json"
    broken.write_text('{"format": "affordance-labels/1", "labels": [}')
    with pytest.raises(LabelError, match=r"broken\.labels\.json: not valid JSON \(.*line 1"):
        load_labels(broken)
    broken.write_text("[1, 2]")
    with pytest.raises(LabelError, match="top level must be a JSON object"):
        load_labels(broken)


def test_unlabelled_regions_are_optional(tmp_path):
    path = tmp_path / "room.labels.json"
    document = json.loads(save_labels(path, full_room()).read_text())
    del document["unlabelled_regions"]
    path.write_text(json.dumps(document))
    assert load_labels(path) == replace(full_room(), unlabelled_regions=())


# ------------------------------------------------------------------------------------ place matching


def test_match_places_found_false_and_ignored():
    region = UnlabelledRegion(((9, 9), (11, 9), (11, 11), (9, 11)))
    labels = room(
        Label("perch", 0.0, start=(0.0, 0.0), end=(1.0, 0.0)),
        Label("perch", math.pi / 2, at=(3.0, 0.0)),
        Label("lean", 0.0, at=(5.0, 5.0)),
        Label("perch", 0.0, at=(10.0, 10.0)),  # inside the region: nothing can find it
        regions=(region,),
    )
    skeletons = np.array(
        [
            [0.5, 0.1, 0.2],  # finds the segment
            [1.1, 0.0, 6.2],  # also the segment (end cap, across the wrap): not false
            [3.0, 0.2, 0.0],  # at the point but facing 1.57 rad away: false
            [5.0, 5.0, 0.0],  # on a label of another affordance: false
            [10.0, 10.0, 0.0],  # in the unlabelled region, on a label: ignored
            [10.0, 9.5, 3.0],  # in the unlabelled region, on nothing: ignored, not false
            [3.0, 0.149, 1.57 + 0.39],  # the point, at both tolerances' edges
        ]
    )
    match = match_places(labels, "perch", skeletons)
    assert [label.at or label.start for label in match.labels] == [(0.0, 0.0), (3.0, 0.0), (10.0, 10.0)]
    assert match.found.tolist() == [True, True, False]
    assert match.false.tolist() == [False, False, True, True, False, False, False]
    assert match.ignored.tolist() == [False, False, False, False, True, True, False]
    assert match.recall == pytest.approx(2 / 3)
    tight = match_places(labels, "perch", skeletons, xy_tolerance=0.1, theta_tolerance=0.1)
    assert tight.found.tolist() == [True, False, False]
    empty = match_places(labels, "perch", np.zeros((0, 3)))
    assert empty.found.tolist() == [False] * 3 and empty.false.shape == (0,)


def test_labels_move_with_a_levelled_cloud_and_refuse_a_turned_one():
    """Labels in a cloud's own frame go where gravity alignment takes the cloud: a turn about z and a shift
    move their points, facings and unlabelled regions alike; a cloud turned onto another up has no plan."""
    region = UnlabelledRegion(((0, 0), (1, 0), (1, 1), (0, 1)))
    labels = room(
        Label("perch", 0.0, at=(1.0, 0.0), z=0.7),
        Label("perch", math.pi, start=(0.0, 2.0), end=(1.0, 2.0)),
        regions=(region,),
    )
    turn = np.eye(4)
    turn[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]  # 90 degrees about z
    turn[:3, 3] = [0.5, -1.0, -0.07]  # and the floor moved to z = 0
    moved = labels.moved(turn)
    point, segment = moved.labels
    assert point.at == pytest.approx((0.5, 0.0)) and point.facing == pytest.approx(math.pi / 2)
    assert point.z == 0.7  # a torso height above the floor stays one
    assert segment.start == pytest.approx((-1.5, -1.0)) and segment.end == pytest.approx((-1.5, 0.0))
    assert segment.facing == pytest.approx(3 * math.pi / 2)
    assert moved.unlabelled(np.array([[0.0, -0.5]])).tolist() == [True]  # the square's centre, moved
    assert moved.unlabelled(np.array([[0.5, 0.5]])).tolist() == [False]
    tilt = math.radians(2.0)  # a slight tilt levelled: points move by at most their height's share
    level = np.eye(4)
    level[1:3, 1:3] = [[math.cos(tilt), -math.sin(tilt)], [math.sin(tilt), math.cos(tilt)]]
    assert labels.moved(level).labels[0].at == pytest.approx((1.0, 0.0))
    up = np.eye(4)
    up[1:3, 1:3] = [[0.0, -1.0], [1.0, 0.0]]  # a y-up cloud turned z-up: its labels cannot be on its plan
    with pytest.raises(LabelError, match="turned this cloud 90 deg; level it first"):
        labels.moved(up)


# -------------------------------------------------------------------------------------------- plot


def test_colours_follow_the_sorted_names():
    colours = affordance_colours({"b", "a", "c"})
    assert colours == affordance_colours(["c", "a", "b"])
    assert len(set(colours.values())) == 3


def test_plot_writes_a_readable_png(tmp_path):
    import matplotlib.image

    rng = np.random.default_rng(1)
    floor = rng.uniform((0, 0, -0.01), (4, 3, 0.01), (20000, 3))
    sofa = rng.uniform((1, 2.4, 0), (2.5, 2.9, 0.8), (5000, 3))
    labels = room(
        Label("perch", -1.5708, start=(1.2, 2.2), end=(2.3, 2.2), note="sofa"),
        Label("lean", 0.0, at=(0.5, 0.8)),
        regions=(UnlabelledRegion(((3, 0), (4, 0), (4, 1), (3, 1)), "not scanned"),),
    )
    points = np.vstack([floor, sofa])
    g = PoseGrid.over_footprint((0, 0, 4, 3), 0.6, 0.1)
    truth = {name: ground_truth(labels, name, g) for name in ("perch", "lean")}
    path = plot_labels(points, labels, tmp_path / "labels.png", grid=g, ground_truth=truth)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert path.stat().st_size > 20_000
    image = matplotlib.image.imread(path)
    assert 400 < image.shape[0] < 2000 and 400 < image.shape[1] < 2000
    assert image[..., :3].std() > 0.05


# -------------------------------------------------------------------------------- the real rooms


@pytest.fixture(scope="module")
def real_rooms(shared_data):
    from affordcore.geometry.scene import load_cloud

    rooms = []
    for path in sorted((shared_data / "rooms").glob("*.labels.json")):
        labels = load_labels(path)
        rooms.append((path, labels, load_cloud(path.parent / labels.cloud)))
    assert len(rooms) >= 2
    return rooms


@pytest.mark.slow  # loading the two real clouds takes seconds
def test_real_label_files(real_rooms, tmp_path):
    from affordcore.geometry.skeleton import all_skeletons

    for path, labels, cloud in real_rooms:
        footprint = (*cloud.points[:, :2].min(axis=0), *cloud.points[:, :2].max(axis=0))
        grids = {
            skeleton.affordance: PoseGrid.over_footprint(footprint, skeleton.torso_height, 0.1)
            for skeleton in all_skeletons()
        }
        assert set(labels.affordances) <= set(grids), f"{path.name}: labels of types with no skeleton"
        for i, label in enumerate(labels.labels):
            alone = ground_truth(replace(labels, labels=(label,)), label.affordance, grids[label.affordance])
            assert alone.counts()[0] > 0, f"{path.name}: labels[{i}] yields no positive pose"
        counts = class_counts(labels, grids)
        print(f"\n{path.name}: {counts}")
        for name, count in counts.items():
            if labels.of(name):  # the paper's 1:523 to 1:12,067, in a small room: loose bounds only
                assert 20 < count.negatives / count.positives < 50_000, (path.name, name, count)
        save_labels(tmp_path / path.name, labels)
        assert load_labels(tmp_path / path.name) == labels
        truth = {name: ground_truth(labels, name, g) for name, g in grids.items()}
        png = tmp_path / f"{path.stem}.png"
        plot_labels(cloud.points, labels, png, grid=next(iter(grids.values())), ground_truth=truth)
        assert png.stat().st_size > 50_000
