"""Depth images to points: the one back-projection of the project (pinhole camera; x right, y down, z
forward).

Each `pixel_step` x `pixel_step` block of pixels becomes one point: the mean of the block's measured depths,
on the ray through the block's centre. Kinect-class depth comes in disparity steps with noise of the same
size; averaging a block smooths both, the way the sensor's own correlation window would at a lower resolution
(docs/services.md has the measured gain over taking every n-th pixel). A block that straddles a depth edge
keeps its mean, a point between foreground and background like the sensor's own flying pixels: dropping such
blocks lost most of the gain. `pixel_step` 1 is every measured pixel, as it is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DepthImage:
    """A 16-bit depth image and how to read it."""

    pixels: np.ndarray  # (H, W) uint16
    intrinsics: np.ndarray  # 3 x 3 pinhole matrix, in pixels
    scale: float = 0.001  # metres per unit (millimetres)
    invalid_value: int = 65535  # besides 0, the value that means no measurement (0: no other)


def back_project(
    image: DepthImage, pixel_step: int = 1, min_range: float = 0.0, max_range: float = np.inf
) -> np.ndarray:
    """Points (N, 3) in the camera frame, one per block with a measurement whose mean depth lies within
    [min_range, max_range]; a partial block at the right or bottom edge is left out."""
    depth = np.asarray(image.pixels)
    if depth.ndim != 2:
        raise ValueError(f"a depth image must be 2-D, got shape {depth.shape}")
    intrinsics, depth_scale, invalid_value = image.intrinsics, image.scale, image.invalid_value
    step = int(pixel_step)
    if step < 1:
        raise ValueError(f"pixel_step must be at least 1, got {pixel_step}")
    rows, columns = depth.shape[0] // step, depth.shape[1] // step
    depth = depth[: rows * step, : columns * step]
    measured = depth != 0
    if invalid_value:
        measured &= depth != invalid_value
    values = np.where(measured, depth, 0)
    total, count = np.zeros((rows, columns)), np.zeros((rows, columns), dtype=np.int32)
    for row in range(step):  # strided sums: faster than summing a (rows, step, columns, step) view
        for column in range(step):
            total += values[row::step, column::step]
            count += measured[row::step, column::step]
    z = np.divide(total, count, out=np.zeros_like(total), where=count > 0) * depth_scale
    keep = (count > 0) & (z >= min_range) & (z <= max_range)
    v, u = np.nonzero(keep)
    z = z[keep]
    centre = (step - 1) / 2
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    return np.column_stack([(u * step + centre - cx) / fx * z, (v * step + centre - cy) / fy * z, z])
