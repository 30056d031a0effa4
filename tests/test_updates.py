"""Map updates in proportion to the change: rescoring only the poses near a change of the room gives the
scores and maps of a mapping from scratch, and rescores a part of the room that the change bounds."""

from __future__ import annotations

import numpy as np
import pytest
from test_features import _room

from affordcore.example import box_surface_points
from affordcore.geometry.features import FeatureLayout
from affordcore.geometry.fields import compute_fields, voxel_down_sample
from affordcore.geometry.skeleton import get_skeleton
from affordcore.learn.model import AffordanceModel
from affordcore.learn.trees import TreeEnsemble
from affordcore.mapping import inference
from affordcore.mapping.inference import score_poses
from affordcore.mapping.pipeline import RoomMapper, map_affordances, pose_grid
from affordcore.mapping.updates import ModelState, reach_voxels, updated_scores
from affordcore.settings import NormalSettings, Settings, VoxelSettings

# the local layout: truncated distance, steep normals facing the scanned floor (docs/geometry.md)
LAYOUT = FeatureLayout(1.0, 0.25, 0.10, distance_cap=0.5, steep_facing="floor")
BOX = ((4.0, 4.2, 0.0), (4.3, 4.5, 0.3))  # a 30 cm box put down in the free part of the room


def _fields(points, facing="floor"):
    return compute_fields(points, VoxelSettings(), NormalSettings(steep_facing=facing))


def _rooms(facing: str) -> dict:
    base = _room(size=6.0)
    rng = np.random.default_rng(3)
    with_box = np.concatenate([base, box_surface_points(*map(np.array, BOX), 2000, rng)])
    beyond = np.concatenate(
        [base, box_surface_points(np.array([6.2, 1.0, 0]), np.array([6.5, 1.3, 0.4]), 2000, rng)]
    )
    clouds = {"base": base, "box": with_box, "beyond": beyond}
    return {name: _fields(points, facing) for name, points in clouds.items()}


@pytest.fixture(scope="module")
def rooms():
    """The room, the room with the box in it, and the room grown by a box beyond its footprint."""
    return _rooms("floor")


def _linear(fields, skeleton, layout, weights):
    grid = pose_grid(fields, skeleton, Settings())
    return grid, score_poses(fields, skeleton, grid, layout, weights, 0.2)


def _update(rooms, after: str, layout: FeatureLayout):
    skeleton = get_skeleton("sitting-relaxing")
    weights = np.random.default_rng(5).normal(size=layout.n_features)
    grid, scores = _linear(rooms["base"], skeleton, layout, weights)
    previous = ModelState(rooms["base"], grid, scores, scores)
    new_grid, full = _linear(rooms[after], skeleton, layout, weights)
    updated, stale, report = updated_scores(previous, rooms[after], new_grid, skeleton, layout, weights, 0.2)
    return new_grid, full, updated, stale, report, skeleton


def test_an_update_equals_a_full_scoring_and_rescores_only_near_the_change(rooms):
    grid, full, updated, stale, report, skeleton = _update(rooms, "box", LAYOUT)
    np.testing.assert_array_equal(updated, full)
    assert report.reason == "" and 0 < report.fraction < 0.5
    # every cell scored afresh lies within reach of the box and the truncated distance's cap beyond it (in
    # each axis: patches are scored over their bounding boxes)
    reach = reach_voxels(skeleton, LAYOUT, 0.1) * 0.1 + LAYOUT.distance_cap + 0.2
    ix, iy = np.nonzero(stale)
    assert grid.x[ix].min() > BOX[0][0] - reach and grid.x[ix].max() < BOX[1][0] + reach
    assert grid.y[iy].min() > BOX[0][1] - reach and grid.y[iy].max() < BOX[1][1] + reach


def test_the_truncated_distance_is_what_bounds_the_change(rooms):
    *_, capped, _ = _update(rooms, "box", LAYOUT)
    untruncated = FeatureLayout(1.0, 0.25, 0.10, distance_cap=None, steep_facing="floor")
    _, full, updated, _, report, _ = _update(rooms, "box", untruncated)
    np.testing.assert_array_equal(updated, full)  # still exact, only less local
    assert report.fraction > 1.2 * capped.fraction


def test_a_mapper_refuses_fields_whose_normals_face_otherwise_than_its_layout(rooms):
    with pytest.raises(ValueError, match="steep normals facing 'floor' for a layout of 'centre'"):
        RoomMapper([], FeatureLayout(1.0, 0.25, 0.10), Settings()).maps(rooms["base"])


def test_an_update_of_the_paper_s_layout_is_exact_too():
    """The default layout (untruncated distance, steep normals facing the cloud's mean point): a change
    reaches further, but what an update rescores is still every pose whose score changed."""
    paper = FeatureLayout(1.0, 0.25, 0.10)
    _, full, updated, _, report, _ = _update(_rooms("centre"), "box", paper)
    assert report.reason == ""
    np.testing.assert_array_equal(updated, full)


def test_an_update_of_soft_fields_is_exact_too():
    """Soft fields (VoxelSettings.fields): the collision feature reads their own occupancy, which a change
    alters over more voxels than the binary one; an update still rescores every pose whose score changed."""
    base = _room(size=6.0)
    box = box_surface_points(*map(np.array, BOX), 2000, np.random.default_rng(3))
    settings = (VoxelSettings(fields="soft"), NormalSettings(steep_facing="floor"))
    rooms = {
        "base": compute_fields(base, *settings),
        "box": compute_fields(np.concatenate([base, box]), *settings),
    }
    soft = FeatureLayout(1.0, 0.25, 0.10, distance_cap=0.5, steep_facing="floor", soft_fields=True)
    _, full, updated, stale, report, _ = _update(rooms, "box", soft)
    assert report.reason == "" and 0 < report.fraction < 0.6
    np.testing.assert_array_equal(updated, full)
    with pytest.raises(ValueError, match="fields of the other kind for a layout of binary fields"):
        RoomMapper([], LAYOUT, Settings()).maps(rooms["base"])


def test_a_room_that_grows_beyond_its_footprint_is_updated_exactly(rooms):
    grid, full, updated, stale, report, _ = _update(rooms, "beyond", LAYOUT)
    assert grid.shape != pose_grid(rooms["base"], get_skeleton("sitting-relaxing"), Settings()).shape
    np.testing.assert_array_equal(updated, full)
    assert report.fraction < 1 and stale[-1].all()  # the new cells are scored


def _cascade() -> AffordanceModel:
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(0)
    X = rng.normal(size=(2000, LAYOUT.n_features)).astype(np.float32)
    y = (X[:, 0] + X[:, 40] > 1.5).astype(int)
    trees = HistGradientBoostingClassifier(max_iter=15, max_depth=4, random_state=0).fit(X, y)
    skeleton = get_skeleton("sitting-relaxing")
    return AffordanceModel(
        affordance="sitting-relaxing",
        layout=LAYOUT.describe(),
        fingerprint=LAYOUT.fingerprint,
        weights=rng.normal(size=LAYOUT.n_features),
        bias=0.1,
        threshold=0.0,
        learner="cascade",
        skeleton={"joints": skeleton.joints.tolist(), "torso_height": skeleton.torso_height},
        rescorer={"fraction": 0.05, "max_poses": 3000, "trees": TreeEnsemble.from_sklearn(trees).to_dict()},
    )


def test_a_room_mapper_gives_the_maps_of_a_mapping_from_scratch_rescoring_less(rooms, monkeypatch):
    model, settings = _cascade(), Settings()
    mapper = RoomMapper([model], LAYOUT, settings)
    mapper.maps(rooms["base"])
    assert mapper.reports[model.affordance].reason == "no previous map"
    rescored = []
    real_features_at = inference.features_at
    monkeypatch.setattr(
        inference, "features_at", lambda *a: rescored.append(len(a[-1])) or real_features_at(*a)
    )
    updated = mapper.maps(rooms["box"])[model.affordance]
    second_stage_updated = rescored.pop()
    scratch = map_affordances(rooms["box"], LAYOUT, [model], settings)[model.affordance]
    second_stage_full = rescored.pop()
    np.testing.assert_array_equal(updated.scores, scratch.scores)
    np.testing.assert_array_equal(updated.skeletons, scratch.skeletons)
    assert updated.place_threshold == scratch.place_threshold
    assert (updated.scores > -1e30).sum() > 100  # the second stage rescored something to compare
    assert 0 < mapper.reports[model.affordance].fraction < 0.5
    assert second_stage_updated < second_stage_full / 2  # the trees reread only near the box


def test_thinning_for_normals_keeps_every_other_point_when_a_point_lands_beyond_the_cloud():
    points = np.random.default_rng(0).uniform(0, 2, (20000, 3))
    before = voxel_down_sample(points, 0.1)
    after = voxel_down_sample(np.vstack([points, [[-1.03, -2.01, -0.5]]]), 0.1)
    assert len(after) == len(before) + 1
    kept = {tuple(p) for p in after.tolist()}
    assert all(tuple(p) in kept for p in before.tolist())


@pytest.mark.parametrize("estimator", ["nearest", "cube"])
def test_a_normal_cache_estimates_only_near_a_change_and_gives_the_fields_of_a_fresh_estimate(
    rooms, estimator
):
    from affordcore.mapping.updates import NormalCache

    rng = np.random.default_rng(3)
    normal_settings = NormalSettings(estimator=estimator)
    base = _room(size=6.0)
    with_box = np.concatenate([base, box_surface_points(*map(np.array, BOX), 2000, rng)])
    cache = NormalCache()
    compute_fields(base, VoxelSettings(), normal_settings, estimator=cache)
    assert cache.estimated == len(cache.points)  # the first cloud: every normal
    cached = compute_fields(with_box, VoxelSettings(), normal_settings, estimator=cache)
    assert 0 < cache.estimated < 0.1 * len(cache.points)
    fresh = compute_fields(with_box, VoxelSettings(), normal_settings)
    np.testing.assert_array_equal(cached.occupancy, fresh.occupancy)
    np.testing.assert_allclose(cached.normals, fresh.normals, atol=1e-5)
    # the same cloud in another order (an assembler's map listed anew) less one point: little to estimate,
    # and still the fields of a fresh estimate
    shuffled = rng.permutation(with_box)[:-1]
    cached = compute_fields(shuffled, VoxelSettings(), normal_settings, estimator=cache)
    assert cache.estimated < 0.01 * len(cache.points)
    fresh = compute_fields(shuffled, VoxelSettings(), normal_settings).normals
    differ = ~np.isclose(cached.normals, fresh, rtol=0, atol=1e-5)
    # a cube's points are those of its cells: a mean summed in another order that lands on a cell's face by
    # its last bit falls in the next cell, so a voxel or two may carry the other side's normal
    assert differ.sum() <= (0 if estimator == "nearest" else 1e-5 * differ.size)
