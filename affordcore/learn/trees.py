"""A boosted ensemble of binary decision trees as plain arrays: stored in JSON, evaluated with numpy.

Model files must be data, not code (a pickled scikit-learn model runs whatever it holds when loaded), and
inference should not need scikit-learn. So the second stage's trees are kept as node tables, all trees in
one table with per-tree roots: a node splits on ``feature <= threshold`` (NaN goes where ``missing_left``
says), a leaf holds its value, and the ensemble's log-odds is ``baseline + sum of the leaves reached``.
Every tree is walked at once, one level per step, so the cost is (depth x trees x rows) vector operations.
For the walk each tree is laid out as a complete binary tree (`_Complete`): the children of position p are
2p + 1 and 2p + 2, so a step needs no gather of child links, and a leaf above the deepest level is carried
down to it by splits whose two sides lead to the same value.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

COMPLETE_POSITIONS = 1 << 22  # at most this many positions in the complete layout, beyond: the node tables
WALK_CELLS = 1 << 18  # (rows x trees) walked at once: the walk's position arrays stay in the cache


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

    def log_odds(self, X: np.ndarray, chunk: int | None = None) -> np.ndarray:
        """The ensemble's raw score of each row of X (n, n_features), float64; rows go in chunks (by default
        of about `WALK_CELLS` / trees rows) so the (rows x trees) walk stays in the cache."""
        X = np.ascontiguousarray(X)
        chunk = chunk or int(np.clip(WALK_CELLS // len(self.roots), 256, 2048))
        out = np.empty(len(X), dtype=np.float64)
        walk = self._walk_complete if self._complete is not None else self._walk_nodes
        for start in range(0, len(X), chunk):
            rows = X[start : start + chunk]
            index = np.int32 if rows.size < 2**31 else np.int64  # of a value in the chunk
            first = (np.arange(len(rows), dtype=index) * rows.shape[1])[:, None]  # each row's first value
            leaves = walk(rows.ravel(), first, np.isnan(rows).any())
            out[start : start + chunk] = self.baseline + leaves.sum(axis=1)
        return out

    def _walk_complete(self, flat: np.ndarray, first: np.ndarray, missing: bool) -> np.ndarray:
        """(rows, trees) leaf values, every tree walked in its complete layout. Positions are absolute (a
        tree's base plus its own position), so a level is one gather of the splits' (feature, threshold)
        records, one of the rows' values and in-place arithmetic: the gathers are what a level costs."""
        complete = self._complete
        splits = complete.splits32 if flat.dtype == np.float32 else complete.splits64
        position = np.repeat(complete.tree_base[None], len(first), axis=0)
        for _ in range(self.depth):
            split = splits[position]
            values = flat[split["feature"] + first]
            go_left = values <= split["threshold"]
            if missing:
                go_left = np.where(np.isnan(values), complete.missing_left[position], go_left)
            position *= 2  # children of base + p: base + 2p + 1 (left) and base + 2p + 2
            position += complete.child_step
            position -= go_left
        return complete.value[position + complete.leaf_shift]

    def _walk_nodes(self, flat: np.ndarray, first: np.ndarray, missing: bool) -> np.ndarray:
        """(rows, trees) leaf values, every tree walked through the node tables: for trees too deep for
        the complete layout."""
        # children[2 k] is node k's right child, children[2 k + 1] its left: one gather per level
        children = np.column_stack([self.right, self.left]).ravel()
        feature = np.maximum(self.feature, 0)  # leaves read any column and point back at themselves
        node = np.broadcast_to(self.roots, (len(first), len(self.roots)))
        for _ in range(self.depth):
            values = flat[first + feature[node]]
            go_left = values <= self.threshold[node]
            if missing:
                go_left = np.where(np.isnan(values), self.missing_left[node], go_left)
            node = children[2 * node + go_left]
        return self.value[node]

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


SPLIT32 = np.dtype([("feature", np.int32), ("threshold", np.float32)])  # a split for float32 rows
SPLIT64 = np.dtype([("feature", np.int32), ("threshold", np.float64)], align=True)  # ... for float64 rows


@dataclass(frozen=True)
class _Complete:
    """Each tree as a complete binary tree of the ensemble's depth: split positions (trees, 2^depth - 1)
    flattened tree by tree, then leaf values (trees, 2^depth). A walk that ends at position p of the last
    level reads leaf value p - (2^depth - 1) of its tree, the value the node tables' walk reaches: a leaf
    above the last level fills its whole subtree (the node tables' leaves point back at themselves, so
    both of its children are itself), and a node the tables leave unsplit at the depth holds 0 as there.
    A split's feature (0 at a carried-down leaf: either side leads to the same value) and threshold are one
    record, so a level of the walk gathers them at once."""

    splits32: np.ndarray  # SPLIT32: thresholds as the largest float32 at or below each, for float32 rows
    splits64: np.ndarray  # SPLIT64: the thresholds themselves, for float64 rows
    missing_left: np.ndarray  # bool
    value: np.ndarray  # float64 leaf values
    tree_base: np.ndarray  # (trees,) int32: each tree's first split position
    child_step: np.ndarray  # (trees,) int32, 2 - tree_base: position a's child is 2a + this - go_left
    leaf_shift: np.ndarray  # (trees,) int32: added to a last level's position, the index of its leaf value

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
        tree_base = (np.arange(len(node)) * n_splits).astype(np.int32)
        return cls(
            splits32=_records(SPLIT32, feature, threshold32),
            splits64=_records(SPLIT64, feature, threshold),
            missing_left=trees.missing_left[splits].ravel(),
            value=trees.value[node].ravel(),
            tree_base=tree_base,
            child_step=2 - tree_base,
            leaf_shift=(np.arange(len(node)) * n_leaves - n_splits).astype(np.int32) - tree_base,
        )


def _records(dtype: np.dtype, feature: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    records = np.empty(len(feature), dtype=dtype)
    records["feature"], records["threshold"] = feature, threshold
    return records
