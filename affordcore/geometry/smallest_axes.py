"""The axis of least spread of groups of points from their moment sums, compiled by numba (for
`geometry/normals.py`).

One group at a time in scalar code: numpy's version held a dozen arrays the size of the groups through each
step of the eigensolver, and those passes over memory were much of the neighbour-free normals' time. The
solver is the closed form open3d's `estimate_normals` uses (D. Eberly, "A Robust Eigensolver for 3x3 Symmetric
Matrices"), operation for operation, so the normals are open3d's to the last bit or nearly. Imported where
normals are first estimated (affordcore.compiled).
"""

from __future__ import annotations

import math

import numpy as np

from ..compiled import compiled


@compiled
def smallest_axes(sums):
    """(m, 3) unit eigenvectors of the smallest eigenvalue of each group's covariance E[p p^T] - E[p] E[p]^T,
    from `sums` (10, m): the count, the sums of x, y, z, then of xx, xy, xz, yy, yz, zz. (0, 0, 1) for fewer
    than 3 points (open3d's rule) or no spread at all."""
    m = sums.shape[1]
    axes = np.empty((m, 3))
    for g in range(m):
        count = sums[0, g]
        if count < 3:
            axes[g, 0], axes[g, 1], axes[g, 2] = 0.0, 0.0, 1.0
            continue
        mx, my, mz = sums[1, g] / count, sums[2, g] / count, sums[3, g] / count
        c00 = sums[4, g] / count - mx * mx
        c01 = sums[5, g] / count - mx * my
        c02 = sums[6, g] / count - mx * mz
        c11 = sums[7, g] / count - my * my
        c12 = sums[8, g] / count - my * mz
        c22 = sums[9, g] / count - mz * mz
        axes[g, 0], axes[g, 1], axes[g, 2] = _axis(c00, c01, c02, c11, c12, c22)
    return axes


@compiled
def _axis(c00, c01, c02, c11, c12, c22):
    scale = max(c00, c01, c02, c11, c12, c22)  # the largest entry, as open3d scales the matrix
    if scale == 0:
        return 0.0, 0.0, 1.0
    a00, a01, a02, a11, a12, a22 = (
        c00 / scale,
        c01 / scale,
        c02 / scale,
        c11 / scale,
        c12 / scale,
        c22 / scale,
    )
    off = a01 * a01 + a02 * a02 + a12 * a12
    if off <= 0:  # diagonal: the smallest entry's axis
        if a00 < a11 and a00 < a22:
            return 1.0, 0.0, 0.0
        if a11 < a00 and a11 < a22:
            return 0.0, 1.0, 0.0
        return 0.0, 0.0, 1.0
    q = (a00 + a11 + a22) / 3
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = math.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + off * 2) / 6)
    d00 = b11 * b22 - a12 * a12
    d01 = a01 * b22 - a12 * a02
    d02 = a01 * a12 - b11 * a02
    half = min(max((b00 * d00 - a01 * d01 + a02 * d02) / (p * p * p) * 0.5, -1.0), 1.0)
    angle = math.acos(half) / 3
    beta2 = math.cos(angle) * 2
    beta0 = math.cos(angle + 2.09439510239319549) * 2
    beta1 = -(beta0 + beta2)
    e0, e1, e2 = q + p * beta0, q + p * beta1, q + p * beta2
    upper = half >= 0
    # first the axis of the eigenvalue at the end of the spectrum that stands apart, then the middle one's in
    # the plane perpendicular to it, then the third as their cross product
    f0, f1, f2 = _end_axis(a00, a01, a02, a11, a12, a22, e2 if upper else e0)
    if (e2 < e0 and e2 < e1) if upper else (e0 < e1 and e0 < e2):
        return f0, f1, f2
    s0, s1, s2 = _middle_axis(a00, a01, a02, a11, a12, a22, f0, f1, f2, e1)
    if e1 < e0 and e1 < e2:
        return s0, s1, s2
    if upper:
        return _cross(s0, s1, s2, f0, f1, f2)
    return _cross(f0, f1, f2, s0, s1, s2)


@compiled
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@compiled
def _end_axis(a00, a01, a02, a11, a12, a22, value):
    """The eigenvector of `value`: the longest cross product of two rows of A - value I."""
    r00, r11, r22 = a00 - value, a11 - value, a22 - value
    x0, x1, x2 = _cross(r00, a01, a02, a01, r11, a12)
    y0, y1, y2 = _cross(r00, a01, a02, a02, a12, r22)
    z0, z1, z2 = _cross(a01, r11, a12, a02, a12, r22)
    dx, dy, dz = x0 * x0 + x1 * x1 + x2 * x2, y0 * y0 + y1 * y1 + y2 * y2, z0 * z0 + z1 * z1 + z2 * z2
    if dz > max(dx, dy):
        return z0 / math.sqrt(dz), z1 / math.sqrt(dz), z2 / math.sqrt(dz)
    if dy > dx:
        return y0 / math.sqrt(dy), y1 / math.sqrt(dy), y2 / math.sqrt(dy)
    return x0 / math.sqrt(dx), x1 / math.sqrt(dx), x2 / math.sqrt(dx)


@compiled
def _middle_axis(a00, a01, a02, a11, a12, a22, x, y, z, value):
    """The eigenvector of `value` perpendicular to (x, y, z): from the 2x2 problem in a basis U, V of the
    plane perpendicular to it."""
    if abs(x) > abs(y):
        inverse = 1 / math.sqrt(x * x + z * z)
        u0, u1, u2 = -z * inverse, 0.0, x * inverse
    else:
        inverse = 1 / math.sqrt(y * y + z * z)
        u0, u1, u2 = 0.0, z * inverse, -y * inverse
    v0, v1, v2 = _cross(x, y, z, u0, u1, u2)
    au0, au1, au2 = (
        a00 * u0 + a01 * u1 + a02 * u2,
        a01 * u0 + a11 * u1 + a12 * u2,
        a02 * u0 + a12 * u1 + a22 * u2,
    )
    av0, av1, av2 = (
        a00 * v0 + a01 * v1 + a02 * v2,
        a01 * v0 + a11 * v1 + a12 * v2,
        a02 * v0 + a12 * v1 + a22 * v2,
    )
    m00 = u0 * au0 + u1 * au1 + u2 * au2 - value
    m01 = u0 * av0 + u1 * av1 + u2 * av2
    m11 = v0 * av0 + v1 * av1 + v2 * av2 - value
    abs00, abs01, abs11 = abs(m00), abs(m01), abs(m11)
    # normalise the 2x2's larger row (by its larger entry) and rotate U, V by it
    by00 = abs00 >= abs11
    big, big_abs = (m00, abs00) if by00 else (m11, abs11)
    if max(big_abs, abs01) <= 0:
        return u0, u1, u2
    if big_abs >= abs01:
        ratio = m01 / big
        norm = 1 / math.sqrt(1 + ratio * ratio)
        big2, other2 = norm, ratio * norm
    else:
        ratio = big / m01
        norm = 1 / math.sqrt(1 + ratio * ratio)
        big2, other2 = ratio * norm, norm
    # the m00 row gives m01 U - m00 V, the m11 row m11 U - m01 V
    cu, cv = (other2, big2) if by00 else (big2, other2)
    return cu * u0 - cv * v0, cu * u1 - cv * v1, cu * u2 - cv * v2
