"""Scores without features: applying a linear model to the fields equals materialising features and a dot
product."""

from __future__ import annotations

import numpy as np
import pytest
from test_features import _fields, _sparse_grid

from affordcore.geometry.features import FeatureLayout, compute_features
from affordcore.geometry.grid import PoseGrid
from affordcore.geometry.skeleton import get_skeleton
from affordcore.mapping.inference import score_poses


@pytest.mark.parametrize("cell_size, step, cap", [(0.25, 0.1, 0.5), (0.10, 0.1, None), (0.5, 0.2, 0.3)])
@pytest.mark.parametrize("affordance", ["sitting-relaxing", "standing-working"])
def test_scores_equal_features_dot_weights(affordance, cell_size, step, cap):
    fields, skeleton = _fields(), get_skeleton(affordance)
    layout = FeatureLayout(cell_size=cell_size, distance_cap=cap)
    sparse = _sparse_grid(fields, skeleton, n_theta=5)
    grid = PoseGrid(sparse.x[:: round(step / 0.1)], sparse.y[:: round(step / 0.1)], sparse.z, sparse.theta)
    rng = np.random.default_rng(7)
    weights, bias = rng.normal(size=layout.n_features), 0.3
    expected = compute_features(fields, skeleton, grid, layout).astype(np.float64) @ weights + bias
    scores = score_poses(fields, skeleton, grid, layout, weights, bias)
    assert scores.shape == grid.shape
    np.testing.assert_allclose(scores.ravel(), expected, rtol=1e-4, atol=1e-3 * np.abs(expected).max())


def test_a_model_of_another_size_is_refused():
    fields, skeleton = _fields(), get_skeleton("sitting-working")
    layout = FeatureLayout(cell_size=0.25)
    with pytest.raises(ValueError, match="3030 weights; the feature layout has 222"):
        score_poses(fields, skeleton, _sparse_grid(fields, skeleton, 2), layout, np.zeros(3030), 0.0)
