"""The loops of `next_views`, compiled by numba: which targets a camera at each position would see, and
what each heading of it would gain. Per (position, target) pair the line of sight is marched until the
first occupied voxel, so a pair costs what its line needs and no (positions, headings, targets) array is
ever made. Imported where the views are computed (affordcore.compiled).
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import compiled


@compiled
def sight_azimuths(eyes, targets, state, origin, resolution, occupied, ranges, elevations, out):
    """out[p, t] (float32, NaN where not seen): the azimuth (radians, from +x) of target t from eye p, where
    it lies within `ranges` (min, max, m) and `elevations` (low, high, radians above the horizon) and no
    voxel of `state` equal to `occupied` lies on the line to it. The line is sampled every half voxel; the
    last voxel and a half before the target are its own surroundings, no obstacle."""
    nx, ny, nz = state.shape
    step, own = resolution / 2, 1.5 * resolution
    for p in range(eyes.shape[0]):
        ex, ey, ez = eyes[p, 0], eyes[p, 1], eyes[p, 2]
        for t in range(targets.shape[0]):
            out[p, t] = np.nan
            dx, dy, dz = targets[t, 0] - ex, targets[t, 1] - ey, targets[t, 2] - ez
            plan = math.sqrt(dx * dx + dy * dy)
            distance = math.sqrt(plan * plan + dz * dz)
            if distance < ranges[0] or distance > ranges[1]:
                continue
            elevation = math.atan2(dz, plan)
            if elevation < elevations[0] or elevation > elevations[1]:
                continue
            samples = int(math.ceil(distance / step))
            clear = True
            for s in range(samples):
                share = s / samples
                if (1.0 - share) * distance < own:
                    break
                i = int(math.floor((ex + share * dx - origin[0]) / resolution + 0.5))
                j = int(math.floor((ey + share * dy - origin[1]) / resolution + 0.5))
                k = int(math.floor((ez + share * dz - origin[2]) / resolution + 0.5))
                if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz and state[i, j, k] == occupied:
                    clear = False
                    break
            if clear:
                out[p, t] = math.atan2(dy, dx)


@compiled
def heading_span(azimuth, headings, half_fov):
    """The headings (first, count) of `headings` evenly spaced ones (heading h at 2 pi h / headings) whose
    horizontal field of view (half-width `half_fov`, radians) holds the azimuth; the first may be negative
    or past the last (taken modulo `headings`)."""
    spacing = 2 * math.pi / headings
    first = int(math.ceil((azimuth - half_fov) / spacing))
    last = int(math.floor((azimuth + half_fov) / spacing))
    return first, min(last - first + 1, headings)


@compiled
def view_gains(azimuths, weight, headings, half_fov, gains):
    """gains[p, h] (float64, zeroed here): the weight of the targets the camera at position p sees turned to
    heading h, from `sight_azimuths`' azimuths."""
    gains[:] = 0.0
    for p in range(azimuths.shape[0]):
        for t in range(azimuths.shape[1]):
            a = azimuths[p, t]
            if math.isnan(a) or weight[t] == 0.0:
                continue
            first, count = heading_span(a, headings, half_fov)
            for h in range(first, first + count):
                gains[p, h % headings] += weight[t]


@compiled
def seen_from(azimuths, heading, headings, half_fov, seen):
    """seen[t] = True where the camera of these azimuths (one position's row), turned to heading number
    `heading`, sees target t."""
    for t in range(azimuths.shape[0]):
        seen[t] = False
        a = azimuths[t]
        if math.isnan(a):
            continue
        first, count = heading_span(a, headings, half_fov)
        for h in range(first, first + count):
            if h % headings == heading:
                seen[t] = True
