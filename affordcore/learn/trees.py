"""A boosted ensemble of binary decision trees as plain arrays: stored in JSON, walked by compiled kernels.

Model files must be data, not code (a pickled scikit-learn model runs whatever it holds when loaded), and
inference should not need scikit-learn. So the second stage's trees are kept as node tables, all trees in
one table with per-tree roots: a node splits on ``feature <= threshold`` (NaN goes where ``missing_left``
says), a leaf holds its value, and the ensemble's log-odds is ``baseline + sum of the leaves reached``.
For the walk (`tree_walk`, numba) each tree is laid out as a complete binary tree (`_Complete`): the children
of position p are 2p + 1 and 2p + 2, so a step reads no child links, and a leaf above the deepest level is
carried down to it by splits whose two sides lead to the same value.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

COMPLETE_POSITIONS = 1 << 22  # at most this many positions in the complete layout, beyond: the node tables


@dataclass(frozen=True)
class TreeEnsemble:
    baseline: float
    roots: np.ndarray  # (n_trees,) index of each tree's root in the node table
    feature: np.ndarray  # (n_nodes,) int32, -1 at leaves
    threshold: np.ndarray  # (n_nodes,) float64
    left: np.ndarray  # (n_nodes,) int32 (a leaf points at itself)
    right: np.ndarray  # (n_nodes,) int32
    missing_left: np.ndarray  # (n_nodes,) bool
    value: np.ndarray  # (n_nodes,) float64, the leaf's contribution
    depth: int  # the deepest leaf

    @classmethod
    def from_sklearn(cls, model) -> TreeEnsemble:
        """The trees of a fitted binary `HistGradientBoostingClassifier` (numerical features only)."""
        tables = [tree.nodes for (tree,) in model._predictors]
        offsets = np.cumsum([0] + [len(t) for t in tables[:-1]])
        nodes = np.concatenate(tables)
        shift = np.repeat(offsets, [len(t) for t in tables])
        leaf = nodes["is_leaf"].astype(bool)
        own = np.arange(len(nodes))
        if nodes["is_categorical"].any():
            raise ValueError("categorical splits are not supported")
        return cls(
            baseline=float(np.ravel(model._baseline_prediction)[0]),
            roots=offsets.astype(np.int32),
            feature=np.where(leaf, -1, nodes["feature_idx"]).astype(np.int32),
            threshold=nodes["num_threshold"].astype(np.float64),
            left=np.where(leaf, own, nodes["left"] + shift).astype(np.int32),
            right=np.where(leaf, own, nodes["right"] + shift).astype(np.int32),
            missing_left=nodes["missing_go_to_left"].astype(bool),
            value=np.where(leaf, nodes["value"], 0.0),
            depth=int(nodes["depth"].max()),
        )

    def log_odds(self, X: np.ndarray) -> np.ndarray:
        """The ensemble's raw score of each row of X (n, n_features), float64."""
        from . import tree_walk

        X = np.ascontiguousarray(X if X.dtype in (np.float32, np.float64) else X.astype(np.float64))
        out = np.full(len(X), self.baseline, dtype=np.float64)
        complete = self._complete
        if complete is not None:
            threshold = complete.threshold32 if X.dtype == np.float32 else complete.threshold64
            # features are finite unless a caller says otherwise: then the faster walk, to the same leaves
            missing_left = complete.missing_left if np.isnan(X).any() else None
            tree_walk.walk_complete(
                X, complete.feature, threshold, missing_left, complete.value, complete.tree_base,
                complete.leaf_shift, self.depth, out,
            )  # fmt: skip
        else:
            feature = np.maximum(self.feature, 0)  # a leaf reads any column and leads back to itself
            tree_walk.walk_nodes(
                X, feature, self.threshold, self.missing_left, self.left, self.right, self.value, self.roots,
                self.depth, out,
            )  # fmt: skip
        return out

    @cached_property
    def _complete(self) -> _Complete | None:
        """The complete layout, or None when it would hold more than `COMPLETE_POSITIONS` positions."""
        if len(self.roots) << self.depth > COMPLETE_POSITIONS:
            return None
        return _Complete.of(self)

    def to_dict(self) -> dict:
        return {
            "baseline": self.baseline,
            "depth": self.depth,
            "roots": self.roots.tolist(),
            "nodes": {
                "feature": self.feature.tolist(),
                "threshold": [float(v) for v in self.threshold],
                "left": self.left.tolist(),
                "right": self.right.tolist(),
                "missing_left": self.missing_left.astype(int).tolist(),
                "value": [float(v) for v in self.value],
            },
        }

    @classmethod
    def from_dict(cls, document: dict) -> TreeEnsemble:
        nodes = document["nodes"]
        feature = np.asarray(nodes["feature"], dtype=np.int32)
        n = len(feature)
        ensemble = cls(
            baseline=float(document["baseline"]),
            roots=np.asarray(document["roots"], dtype=np.int32),
            feature=feature,
            threshold=np.asarray(nodes["threshold"], dtype=np.float64),
            left=np.asarray(nodes["left"], dtype=np.int32),
            right=np.asarray(nodes["right"], dtype=np.int32),
            missing_left=np.asarray(nodes["missing_left"], dtype=bool),
            value=np.asarray(nodes["value"], dtype=np.float64),
            depth=int(document["depth"]),
        )
        arrays = (ensemble.threshold, ensemble.left, ensemble.right, ensemble.missing_left, ensemble.value)
        if any(len(a) != n for a in arrays) or not len(ensemble.roots):
            raise ValueError("tree tables of unequal lengths, or no tree")
        if ensemble.depth < 0:
            raise ValueError(f"a tree depth of {ensemble.depth}")
        for links in (ensemble.left, ensemble.right, ensemble.roots):
            if len(links) and (links.min() < 0 or links.max() >= n):
                raise ValueError("a tree node links outside the node table")
        return ensemble

    @property
    def n_features_used(self) -> int:
        return int(self.feature.max()) + 1 if (self.feature >= 0).any() else 0


@dataclass(frozen=True)
class _Complete:
    """Each tree as a complete binary tree of the ensemble's depth: split positions (trees, 2^depth - 1)
    flattened tree by tree, then leaf values (trees, 2^depth). A walk that ends at position p of the last
    level reads leaf value p - (2^depth - 1) of its tree, the value the node tables' walk reaches: a leaf
    above the last level fills its whole subtree (the node tables' leaves point back at themselves, so
    both of its children are itself), and a node the tables leave unsplit at the depth holds 0 as there."""

    feature: np.ndarray  # int32 (0 at a carried-down leaf: either side leads to the same value)
    threshold32: np.ndarray  # float32: each threshold as the largest float32 at or below it, for float32 rows
    threshold64: np.ndarray  # float64: the thresholds themselves, for float64 rows
    missing_left: np.ndarray  # bool
    value: np.ndarray  # float64 leaf values
    tree_base: np.ndarray  # (trees,) int64: each tree's first split position
    leaf_shift: np.ndarray  # (trees,) int64: added to a last level's position, the index of its leaf value

    @classmethod
    def of(cls, trees: TreeEnsemble) -> _Complete:
        levels, node = [], trees.roots[:, None]  # (trees, 2^level) node of each position of a level
        for _ in range(trees.depth):
            levels.append(node)
            node = np.stack([trees.left[node], trees.right[node]], axis=-1).reshape(len(node), -1)
        splits = np.concatenate(levels, axis=1) if levels else np.empty((len(node), 0), np.int32)
        feature = np.maximum(trees.feature[splits], 0).ravel()
        threshold = trees.threshold[splits].ravel()
        threshold32 = threshold.astype(np.float32)
        above = threshold32.astype(np.float64) > threshold  # rounded up: one float32 step down
        threshold32[above] = np.nextafter(threshold32[above], np.float32(-np.inf))
        n_splits, n_leaves = splits.shape[1], node.shape[1]
        tree_base = np.arange(len(node), dtype=np.int64) * n_splits
        return cls(
            feature=feature.astype(np.int32),
            threshold32=threshold32,
            threshold64=threshold,
            missing_left=trees.missing_left[splits].ravel(),
            value=trees.value[node].ravel(),
            tree_base=tree_base,
            leaf_shift=np.arange(len(node), dtype=np.int64) * n_leaves - n_splits - tree_base,
        )


def compile_walk() -> None:
    """Compile the trees' walk for float32 and float64 rows now (or read it from numba's cache; docs/maps.md
    says what it costs), so that a service's first map does not wait for it and the workers it forks
    afterwards share it."""
    stump = TreeEnsemble.from_dict(
        {
            "baseline": 0.0,
            "depth": 0,
            "roots": [0],
            "nodes": {
                "feature": [-1],
                "threshold": [0.0],
                "left": [0],
                "right": [0],
                "missing_left": [0],
                "value": [0.0],
            },
        }
    )
    for dtype in (np.float32, np.float64):
        stump.log_odds(np.zeros((1, 1), dtype))
        stump.log_odds(np.full((1, 1), np.nan, dtype))  # the walk that reads each split's missing side
