"""A boosted ensemble of binary decision trees as plain arrays: stored in JSON, evaluated with numpy.

Model files must be data, not code (a pickled scikit-learn model runs whatever it holds when loaded), and
inference should not need scikit-learn. So the second stage's trees are kept as node tables, all trees in
one table with per-tree roots: a node splits on ``feature <= threshold`` (NaN goes where ``missing_left``
says), a leaf holds its value, and the ensemble's log-odds is ``baseline + sum of the leaves reached``.
Every tree is walked at once, one level per step, so the cost is (depth x trees x rows) vector operations.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    def log_odds(self, X: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """The ensemble's raw score of each row of X (n, n_features), float64; rows go in chunks so the
        (rows x trees) walk stays small."""
        X = np.ascontiguousarray(X)
        out = np.empty(len(X), dtype=np.float64)
        # children[2 k] is node k's right child, children[2 k + 1] its left: one gather per level
        children = np.column_stack([self.right, self.left]).ravel()
        feature = np.maximum(self.feature, 0)  # leaves read any column and point back at themselves
        for start in range(0, len(X), chunk):
            rows = X[start : start + chunk]
            flat, first = rows.ravel(), (np.arange(len(rows)) * rows.shape[1])[:, None]
            node = np.broadcast_to(self.roots, (len(rows), len(self.roots)))
            missing = np.isnan(flat).any()  # the NaN routing only when there is a NaN
            for _ in range(self.depth):
                values = flat[first + feature[node]]
                go_left = values <= self.threshold[node]
                if missing:
                    go_left = np.where(np.isnan(values), self.missing_left[node], go_left)
                node = children[2 * node + go_left]
            out[start : start + chunk] = self.baseline + self.value[node].sum(axis=1)
        return out

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
        for links in (ensemble.left, ensemble.right, ensemble.roots):
            if len(links) and (links.min() < 0 or links.max() >= n):
                raise ValueError("a tree node links outside the node table")
        return ensemble

    @property
    def n_features_used(self) -> int:
        return int(self.feature.max()) + 1 if (self.feature >= 0).any() else 0
