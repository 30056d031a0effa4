"""Training examples from a data set folder: every positive, a seeded sample of the negatives, features as
the full grid computes them, labels as the ground truth says."""

from __future__ import annotations

import json

import numpy as np
import pytest

from affordcore.geometry.features import FeatureLayout, compute_features
from affordcore.geometry.scene import Cloud, load_cloud, save_cloud
from affordcore.geometry.skeleton import get_skeleton
from affordcore.labels import ground_truth, load_labels
from affordcore.learn.examples import Task, data_set_rooms, load_rooms, room_examples
from affordcore.mapping.pipeline import prepare_scene
from affordcore.settings import GridSettings, Settings
from affordcore.synth.rooms import generate_room
from affordcore.synth.scanner import sample_room_uniform


@pytest.fixture(scope="module")
def data_set(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rooms")
    room = generate_room("workshop", np.random.default_rng(2), "bench-room")
    points, colors = sample_room_uniform(room, np.random.default_rng(2), points_per_m2=300)
    save_cloud(folder / "bench-room.ply", Cloud(points, colors))
    labels = room.labels()
    xs, ys = points[:, 0], points[:, 1]
    labels["unlabelled_regions"] = [
        {
            "polygon": [
                [xs.min(), ys.min()],
                [xs.min() + 1, ys.min()],
                [xs.min() + 1, ys.min() + 1],
                [xs.min(), ys.min() + 1],
            ],
            "note": "left out",
        }
    ]
    (folder / "bench-room.labels.json").write_text(json.dumps(labels))
    (folder / "no-labels.ply").write_bytes((folder / "bench-room.ply").read_bytes())  # ignored: no label file
    return folder


def test_rows_are_every_positive_and_a_sample_of_negatives_with_their_grid_features(data_set):
    settings = Settings(grid=GridSettings(n_theta=4, theta_step=np.pi / 2))
    layout = FeatureLayout(1.0, 0.5, 0.1)
    labels = load_labels(data_set / "bench-room.labels.json")
    affordance = labels.labels[0].affordance
    (room,) = load_rooms(data_set_rooms(data_set), settings)
    task = Task(affordance, settings, layout)
    # the same thing the slow way: every pose's features, then the ground truth's masks
    skeleton = get_skeleton(affordance)
    scene = prepare_scene(load_cloud(data_set / "bench-room.ply"), settings, "none")
    grid = scene.pose_grid(skeleton, settings)
    everything = compute_features(scene.fields, skeleton, grid, layout)
    truth = ground_truth(labels, affordance, grid)
    scored, positive = truth.scored_mask().ravel(), truth.pose_mask().ravel()
    assert scored.sum() < grid.size  # the unlabelled region took some poses out
    n_negatives = int((scored & ~positive).sum())

    every = room_examples(room, task, negatives=0)
    assert every.positives == positive.sum() and len(every.y) == scored.sum()
    np.testing.assert_allclose(_in_order(every.X[every.y > 0]), _in_order(everything[positive]), atol=1e-5)
    np.testing.assert_array_equal(every.weights, 1.0)

    sample = room_examples(room, task, negatives=500, rng=np.random.default_rng(3))
    negatives = sample.X[sample.y < 0]
    assert len(negatives) == 500 and sample.positives == positive.sum()
    # each sampled negative is a real negative pose's row (every column), and stands for n_negatives / 500
    rows = everything[scored & ~positive]
    assert _all_rows_of(negatives, rows)
    np.testing.assert_allclose(sample.weights[sample.y < 0].sum(), n_negatives, rtol=1e-5)
    again = room_examples(room, task, negatives=500, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(sample.X, again.X)


def _in_order(block: np.ndarray) -> np.ndarray:
    """The rows sorted whole (np.sort(axis=0) sorts each column on its own and so pairs values of different
    rows): by the joints' distances and collisions, which both paths compute bit for bit the same, ties by
    the rest."""
    keys = np.column_stack([block[:, :30], np.round(block[:, 30:], 4)])
    return block[np.lexsort(keys.T[::-1])]


def _all_rows_of(rows: np.ndarray, block: np.ndarray) -> bool:
    """Whether every one of `rows` is one of `block`'s rows in every column (to float32 rounding); candidates
    are found by their exact first 30 columns."""
    by_key: dict[bytes, list[int]] = {}
    for index, row in enumerate(np.ascontiguousarray(block[:, :30])):
        by_key.setdefault(row.tobytes(), []).append(index)
    return all(
        np.isclose(block[by_key.get(np.ascontiguousarray(row[:30]).tobytes(), [])], row, atol=1e-5)
        .all(axis=1)
        .any()
        for row in rows
    )


def test_rooms_need_a_label_file(data_set, tmp_path):
    assert [name for name, _, _ in data_set_rooms(data_set)] == ["bench-room"]
    with pytest.raises(FileNotFoundError, match="labels.json"):
        data_set_rooms(tmp_path)


def _room(name, positives, negatives, weight):
    """A room's examples, each row (index, len(name)) so a stacked row tells where it came from; negatives
    weighted `weight`."""
    from affordcore.learn.examples import RoomExamples

    y = np.r_[np.ones(positives), -np.ones(negatives)].astype(np.int8)
    X = np.column_stack([np.arange(len(y)), np.full(len(y), len(name))]).astype(np.float32)
    return RoomExamples(name, X, y, np.where(y > 0, 1.0, weight).astype(np.float32), [], None)


def test_a_stack_keeps_every_positive_and_at_most_the_negatives_asked_for_weighted_to_stand_for_all():
    from affordcore.learn.examples import stack

    rng = np.random.default_rng(0)

    examples = {"a": _room("a", 5, 300, 10.0), "bb": _room("bb", 2, 100, 4.0)}
    whole = stack(examples, ["a", "bb"])
    capped = stack(examples, ["a", "bb"], max_negatives=80, rng=rng)
    assert capped.positives == whole.positives == 7 and int((capped.y < 0).sum()) == 80
    # the kept negatives stand for every negative of both rooms: their weights sum to the whole set's
    assert capped.weights[capped.y < 0].sum() == pytest.approx(whole.weights[whole.y < 0].sum(), rel=0.1)
    assert capped.weights[capped.y > 0].tolist() == [1.0] * 7
    # each kept row is a real row of its room: features and labels travel together
    for x, y in zip(capped.X, capped.y):
        source = examples["a" if x[1] == 1 else "bb"]
        assert source.y[int(x[0])] == y
    assert stack(examples, ["a", "bb"], max_negatives=1000).X.shape == whole.X.shape


def test_a_stack_caps_the_positives_too_weighted_up_and_draws_the_same_negatives_when_they_fit():
    from affordcore.learn.examples import stack

    examples = {"a": _room("a", 400, 300, 10.0), "bb": _room("bb", 200, 100, 4.0)}
    whole = stack(examples, ["a", "bb"])
    both = stack(examples, ["a", "bb"], 80, np.random.default_rng(3), max_positives=150)
    assert int((both.y > 0).sum()) == 150 and int((both.y < 0).sum()) == 80
    for label in (1, -1):  # each class's kept rows stand for all of its rows
        kept, every = both.weights[both.y == label].sum(), whole.weights[whole.y == label].sum()
        assert kept == pytest.approx(every, rel=0.15)
    assert both.weights[both.y > 0] == pytest.approx(np.full(150, 600 / 150))
    for x, y in zip(both.X, both.y):  # features and labels travel together
        assert examples["a" if x[1] == 1 else "bb"].y[int(x[0])] == y
    # a cap the positives fit under draws nothing more: the same rows as negatives alone
    negatives_only = stack(examples, ["a", "bb"], 80, np.random.default_rng(3))
    roomy = stack(examples, ["a", "bb"], 80, np.random.default_rng(3), max_positives=600)
    np.testing.assert_array_equal(roomy.X, negatives_only.X)
    np.testing.assert_array_equal(roomy.weights, negatives_only.weights)
    only_positives = stack(examples, ["a", "bb"], max_positives=60, rng=np.random.default_rng(3))
    assert int((only_positives.y > 0).sum()) == 60 and int((only_positives.y < 0).sum()) == 400


def test_labelled_rooms_find_each_cloud_beside_its_labels_or_in_another_folder(tmp_path):
    """Real rooms as the rebuild's --real finds them: a cloud beside its labels, or rebuilt into another of
    the folders (ScanNet's, whose terms keep the cloud out of the data set); labels with no cloud anywhere
    are left out and named."""
    from affordcore.learn.examples import labelled_rooms, missing_clouds

    shared, rebuilt = tmp_path / "shared", tmp_path / "rebuilt"
    shared.mkdir(), rebuilt.mkdir()
    for name in ("kitchen", "meeting", "lost"):
        (shared / f"{name}.labels.json").write_text("{}")
    (shared / "kitchen.ply").write_text("")
    (rebuilt / "meeting.ply").write_text("")
    (rebuilt / "unlabelled.ply").write_text("")
    rooms = labelled_rooms([shared, rebuilt])
    assert [(r.name, r.cloud, r.labels) for r in rooms] == [
        ("kitchen", shared / "kitchen.ply", shared / "kitchen.labels.json"),
        ("meeting", rebuilt / "meeting.ply", shared / "meeting.labels.json"),
    ]
    assert missing_clouds([shared, rebuilt]) == ["lost"]
    assert labelled_rooms([shared]) == rooms[:1] and missing_clouds([shared]) == ["lost", "meeting"]
