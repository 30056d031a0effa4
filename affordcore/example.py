"""A built-in example room, made on the fly: no data file ships, and the same seed gives the same cloud.

A 6 m x 5 m room with a sofa and coffee table, a desk with a chair, a kitchen counter and a bookshelf,
built from boxes whose surfaces are sampled like a dense scan (with a little range noise). It exists so that
every command has something real to chew on out of the box; the procedural training rooms live elsewhere.
"""

from __future__ import annotations

import numpy as np

from .geometry.scene import Cloud

# (name, (x0, y0, z0), (x1, y1, z1), RGB): axis-aligned boxes, metres, z up, floor at z = 0.
_BOXES = [
    ("floor", (0.0, 0.0, 0.0), (6.0, 5.0, 0.0), (0.55, 0.45, 0.35)),
    ("wall south", (0.0, -0.1, 0.0), (6.0, 0.0, 2.5), (0.85, 0.85, 0.8)),
    ("wall north", (0.0, 5.0, 0.0), (6.0, 5.1, 2.5), (0.85, 0.85, 0.8)),
    ("wall west", (-0.1, 0.0, 0.0), (0.0, 5.0, 2.5), (0.8, 0.85, 0.85)),
    ("wall east, left of the door", (6.0, 0.0, 0.0), (6.1, 3.6, 2.5), (0.8, 0.85, 0.85)),
    ("wall east, over the door", (6.0, 3.6, 2.05), (6.1, 4.5, 2.5), (0.8, 0.85, 0.85)),
    ("wall east, right of the door", (6.0, 4.5, 0.0), (6.1, 5.0, 2.5), (0.8, 0.85, 0.85)),
    # sofa against the west wall, facing +x
    ("sofa base", (0.05, 1.2, 0.0), (0.95, 3.2, 0.42), (0.3, 0.35, 0.6)),
    ("sofa back", (0.05, 1.2, 0.42), (0.3, 3.2, 0.85), (0.3, 0.35, 0.6)),
    ("sofa arm left", (0.05, 1.0, 0.0), (0.95, 1.2, 0.62), (0.3, 0.35, 0.6)),
    ("sofa arm right", (0.05, 3.2, 0.0), (0.95, 3.4, 0.62), (0.3, 0.35, 0.6)),
    ("coffee table", (1.4, 1.7, 0.38), (2.1, 2.7, 0.42), (0.5, 0.3, 0.2)),
    ("coffee table base", (1.5, 1.8, 0.0), (2.0, 2.6, 0.38), (0.5, 0.3, 0.2)),
    # desk by the south wall with a chair in front of it, facing -y
    ("desk top", (3.0, 0.05, 0.71), (4.4, 0.8, 0.75), (0.7, 0.6, 0.45)),
    ("desk leg a", (3.02, 0.07, 0.0), (3.08, 0.13, 0.71), (0.2, 0.2, 0.2)),
    ("desk leg b", (4.32, 0.07, 0.0), (4.38, 0.13, 0.71), (0.2, 0.2, 0.2)),
    ("desk leg c", (3.02, 0.72, 0.0), (3.08, 0.78, 0.71), (0.2, 0.2, 0.2)),
    ("desk leg d", (4.32, 0.72, 0.0), (4.38, 0.78, 0.71), (0.2, 0.2, 0.2)),
    ("monitor", (3.5, 0.15, 0.75), (3.9, 0.2, 1.1), (0.1, 0.1, 0.1)),
    ("chair seat", (3.45, 0.95, 0.43), (3.95, 1.45, 0.47), (0.15, 0.15, 0.15)),
    ("chair back", (3.45, 1.42, 0.47), (3.95, 1.47, 0.95), (0.15, 0.15, 0.15)),
    ("chair post", (3.67, 1.17, 0.05), (3.73, 1.23, 0.43), (0.3, 0.3, 0.3)),
    ("chair foot", (3.45, 0.95, 0.0), (3.95, 1.45, 0.05), (0.3, 0.3, 0.3)),
    # kitchen counter along the north wall
    ("counter", (2.8, 4.4, 0.0), (5.2, 5.0, 0.92), (0.75, 0.75, 0.72)),
    ("counter top", (2.78, 4.37, 0.92), (5.2, 5.0, 0.95), (0.25, 0.25, 0.25)),
    ("wall cabinet", (2.8, 4.65, 1.5), (5.2, 5.0, 2.2), (0.75, 0.75, 0.72)),
    # bookshelf in the south-east corner
    ("bookshelf", (5.6, 0.5, 0.0), (5.98, 1.7, 1.9), (0.45, 0.3, 0.2)),
]


def example_room(seed: int = 0, points_per_m2: float = 900.0, noise: float = 0.004) -> Cloud:
    """The example room as a gravity-aligned cloud with colours (about 150k points)."""
    rng = np.random.default_rng(seed)
    points, colors = [], []
    for _, low, high, rgb in _BOXES:
        sample = box_surface_points(np.array(low), np.array(high), points_per_m2, rng)
        points.append(sample)
        colors.append(np.tile(np.array(rgb, dtype=np.float32), (len(sample), 1)))
    cloud = np.concatenate(points)
    cloud += rng.normal(scale=noise, size=cloud.shape)
    return Cloud(cloud, np.concatenate(colors), source="built-in example room")


def box_surface_points(
    low: np.ndarray, high: np.ndarray, points_per_m2: float, rng: np.random.Generator
) -> np.ndarray:
    """Points spread uniformly over the six faces of an axis-aligned box."""
    size = high - low
    faces = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        area = size[u] * size[v]
        count = rng.poisson(area * points_per_m2)
        for side in (low[axis], high[axis]):
            face = np.empty((count, 3))
            face[:, axis] = side
            face[:, u] = low[u] + rng.random(count) * size[u]
            face[:, v] = low[v] + rng.random(count) * size[v]
            faces.append(face)
    return np.concatenate(faces)
