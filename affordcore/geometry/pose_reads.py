"""The feature rows of scattered poses (`features.features_at`), compiled by numba.

Each pose's row is read pose by pose: the bilinear corners of its joints in the distance and occupancy
fields, and of its cube's normal samples, summed in float32 in the corners' order as the grid's slabs sum
them, and the samples of a cell averaged. numpy had to hold every corner of every sample of a block of
poses to do this (a pose's 64 samples x 4 corners x 12 values); here nothing but the row is written. The
same values as numpy's reads to the bit: the same float32 operations in the same order. Imported when the
first features are read (affordcore.compiled).
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled


@compiled
def read_rows(
    base, theta, distance, occupancy, normals, joint_rows, joint_weights, sample_rows, sample_weights,
    cells, per_cell, out,
):  # fmt: skip
    """Fills `out` (poses, 2 x joints + 3 x cells^3), the normals in the world's frame. Pose p's fields start
    at row base[p] of each field (level, x, y flattened); its heading's corner tables (theta[p]) give each
    read's row offsets (..., 4) and float32 weights. `normals` holds per row the cells' heights x 3 values;
    sample s of the cube's (cells x per_cell)^2 lattice lies in cell column (s // axis // per_cell,
    s % axis // per_cell)."""
    n_joints, n_values, axis = joint_rows.shape[1], normals.shape[1], cells * per_cell
    share = np.float32(1.0 / (per_cell * per_cell))
    cube = np.empty((cells, cells, n_values), np.float32)
    sample = np.empty(n_values, np.float32)
    for p in range(base.shape[0]):
        t, b = theta[p], base[p]
        for j in range(n_joints):
            row, weight = b + joint_rows[t, j, 0], joint_weights[t, j, 0]
            d, o = distance[row, j] * weight, occupancy[row, j] * weight
            for c in range(1, 4):
                row, weight = b + joint_rows[t, j, c], joint_weights[t, j, c]
                d += distance[row, j] * weight
                o += occupancy[row, j] * weight
            out[p, j], out[p, n_joints + j] = d, o
        cube[:] = 0
        for s in range(sample_rows.shape[1]):
            row, weight = b + sample_rows[t, s, 0], sample_weights[t, s, 0]
            for k in range(n_values):
                sample[k] = normals[row, k] * weight
            for c in range(1, 4):
                row, weight = b + sample_rows[t, s, c], sample_weights[t, s, c]
                for k in range(n_values):
                    sample[k] += normals[row, k] * weight
            cx, cy = s // axis // per_cell, s % axis // per_cell
            for k in range(n_values):
                cube[cx, cy, k] += sample[k]
        f = 2 * n_joints  # a cell's normal is its samples' mean, in the world's frame (`read_rows` turns it)
        for cx in range(cells):
            for cy in range(cells):
                for k in range(n_values):
                    out[p, f] = cube[cx, cy, k] * share
                    f += 1
