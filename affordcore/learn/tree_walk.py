"""The walk of a `TreeEnsemble` (affordcore.learn.trees), compiled by numba.

A row's walk down one tree is a chain of dependent reads (split, then the row's value, then the child), so
a plain loop waits on memory at every level. These kernels walk `BLOCK` rows through a tree level by level,
so the reads of different rows overlap, and add each tree's leaf to the rows' sums in tree order: both
kernels sum alike, so they give the same values to the bit when they reach the same leaves. Imported when
trees are first walked (affordcore.compiled).
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled

BLOCK = 32  # rows walked side by side: their positions stay in registers and the first cache level


@compiled
def walk_complete(X, feature, threshold, missing_left, value, tree_base, leaf_shift, depth, out):
    """Adds each tree's leaf to `out` (rows of X), the trees laid out complete: position p's children are
    2p + 1 and 2p + 2 within its tree (positions absolute: the tree's base plus its own), and a walk that ends
    at position p of the last level reads leaf value p + leaf_shift[tree]. `missing_left` None: rows without
    NaN, and numba compiles a walk that reads no split's side for missing values (the walk is bound by its
    chain of loads: one fewer a level makes it 1.7 times as fast, to the same leaves)."""
    position = np.empty(BLOCK, np.int64)
    for start in range(0, X.shape[0], BLOCK):
        rows = min(BLOCK, X.shape[0] - start)
        for tree in range(tree_base.shape[0]):
            base = tree_base[tree]
            position[:rows] = base
            for _ in range(depth):
                for i in range(rows):
                    p = position[i]
                    v = X[start + i, feature[p]]
                    left = v <= threshold[p]
                    if missing_left is not None:  # pruned at compile time for None
                        left |= (v != v) & missing_left[p]  # NaN: the split's side
                    position[i] = 2 * p - base + 2 - left
            shift = leaf_shift[tree]
            for i in range(rows):
                out[start + i] += value[position[i] + shift]


@compiled
def walk_nodes(X, feature, threshold, missing_left, left, right, value, roots, depth, out):
    """As `walk_complete`, through the node tables (a leaf's children are itself, its feature any column)."""
    node = np.empty(BLOCK, np.int64)
    for start in range(0, X.shape[0], BLOCK):
        rows = min(BLOCK, X.shape[0] - start)
        for tree in range(roots.shape[0]):
            node[:rows] = roots[tree]
            for _ in range(depth):
                for i in range(rows):
                    k = node[i]
                    v = X[start + i, feature[k]]
                    node[i] = left[k] if (v <= threshold[k]) | ((v != v) & missing_left[k]) else right[k]
            for i in range(rows):
                out[start + i] += value[node[i]]
