"""Training examples from a data set folder: rows are the scored poses, labels follow the ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from affordcore.features import FeatureLayout, compute_features
from affordcore.labels import ground_truth, load_labels
from affordcore.learn.examples import data_set_rooms, load_examples
from affordcore.pipeline import prepare_scene
from affordcore.scene import Cloud, load_cloud, save_cloud
from affordcore.settings import GridSettings, Settings
from affordcore.skeleton import get_skeleton
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


def test_rows_are_the_scored_poses_in_grid_order(data_set):
    settings = Settings(grid=GridSettings(n_theta=4, theta_step=np.pi / 2))
    layout = FeatureLayout(1.0, 0.5, 0.1)
    affordance = load_labels(data_set / "bench-room.labels.json").labels[0].affordance
    (examples,) = list(load_examples(data_set, affordance, settings, layout))
    # the same thing the slow way: every pose's features, then the ground truth's masks
    skeleton = get_skeleton(affordance)
    scene = prepare_scene(load_cloud(data_set / "bench-room.ply"), settings, "none")
    grid = scene.pose_grid(skeleton, settings)
    everything = compute_features(scene.fields, skeleton, grid, layout)
    truth = ground_truth(load_labels(data_set / "bench-room.labels.json"), affordance, grid)
    scored = truth.scored_mask().ravel()
    assert scored.sum() < grid.size  # the unlabelled region took some poses out
    np.testing.assert_array_equal(examples.X, everything[scored])
    np.testing.assert_array_equal(examples.y > 0, truth.pose_mask().ravel()[scored])
    assert examples.positives > 0


def test_rooms_need_a_label_file(data_set, tmp_path):
    assert [name for name, _, _ in data_set_rooms(data_set)] == ["bench-room"]
    with pytest.raises(FileNotFoundError, match="labels.json"):
        data_set_rooms(tmp_path)
