"""The loops of `visibility`'s range images, compiled by numba: drawing each surface voxel's outline into an
image, and testing every voxel of the lattice against it. The angles (arctan2, the elevation table) stay in
numpy, so these kernels do only what numpy did with temporaries as large as the outlines' bins or the
lattice: comparisons and float32 arithmetic in numpy's order, the same states to the bit. Imported when the
first range image is drawn (affordcore.compiled).
"""

from __future__ import annotations

import numpy as np

from ..compiled import compiled


@compiled
def draw_outlines(first_row, rows, first_column, columns, distance, n_az, image):
    """The nearest range in every bin of `image` (flat, n_el x n_az, inf where none): voxel v covers the
    rows first_row[v] .. + rows[v] and the columns first_column[v] .. + columns[v] (modulo n_az)."""
    for v in range(distance.shape[0]):
        for r in range(rows[v]):
            line = (first_row[v] + r) * n_az
            for c in range(columns[v]):
                b = line + (first_column[v] + c) % n_az
                if distance[v] < image[b]:
                    image[b] = distance[v]


@compiled
def mark_in_front(across, column, z, image, elevation_rows, to_table, resolution, free):
    """Sets free[i, j, k] where voxel (i, j, k) is at least `resolution` nearer than the image's surface in
    its direction: `across` (nx, ny) float32 its column's distance in plan from the sensor, `column` its
    azimuth bin, z (nz,) float32 the layers' heights over the sensor; elevation bins from the sine by
    `elevation_rows` (to_table: the sine's scale into that table). float32 throughout, as numpy did."""
    one, floor = np.float32(1.0), np.float32(1e-6)
    for i in range(across.shape[0]):
        for j in range(across.shape[1]):
            a, c = across[i, j], column[i, j]
            for k in range(z.shape[0]):
                d = np.sqrt(a * a + z[k] * z[k])
                sine = z[k] / max(d, floor)
                row = elevation_rows[np.int32((sine + one) * to_table)]
                if d + resolution <= image[row, c]:
                    free[i, j, k] = True
