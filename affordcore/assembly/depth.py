"""Depth images to points: the one back-projection of the project (pinhole camera; x right, y down, z
forward).

Each `pixel_step` x `pixel_step` block of pixels becomes one point: the mean of the block's measured depths,
on the ray through the block's centre. Kinect-class depth comes in disparity steps with noise of the same
size; averaging a block smooths both, the way the sensor's own correlation window would at a lower resolution
(docs/services.md has the measured gain over taking every n-th pixel). A block that straddles a depth edge
keeps its mean, a point between foreground and background like the sensor's own flying pixels: dropping such
blocks lost most of the gain for registration. The map is another matter: there such points are surfaces
that are not there (in the kitchen they filled 10 cm cells the fused room leaves empty, docs/services.md),
so the assembler's map takes its keyframes with `max_spread`, which drops them.
`pixel_step` 1 is every measured pixel, as it is.
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
    image: DepthImage,
    pixel_step: int = 1,
    min_range: float = 0.0,
    max_range: float = np.inf,
    block_stride: int = 1,
    max_spread: float = 0.0,
) -> np.ndarray:
    """Points (N, 3) in the camera frame, one per block with a measurement whose mean depth lies within
    [min_range, max_range]; a partial block at the right or bottom edge is left out. With `block_stride` n
    only every n-th block along each axis is taken (the blocks at rows and columns 0, n, 2n, ...): the same
    points as every block's, thinned, at 1 / n^2 of the cost. With `max_spread` > 0 a block whose measured
    depths spread over more than that fraction of its mean depth (it straddles a depth edge) is left out."""
    depth = np.asarray(image.pixels)
    if depth.ndim != 2:
        raise ValueError(f"a depth image must be 2-D, got shape {depth.shape}")
    step, stride = int(pixel_step), int(block_stride)
    if step < 1:
        raise ValueError(f"pixel_step must be at least 1, got {pixel_step}")
    if stride < 1:
        raise ValueError(f"block_stride must be at least 1, got {block_stride}")
    rows, columns = depth.shape[0] // step, depth.shape[1] // step
    pitch = step * stride  # pixels from one taken block to the next
    total = count = low = high = None
    for row in range(step):  # integer sums of strided views: no float image, no 4-D reduction
        for column in range(step):
            values = depth[row : rows * step : pitch, column : columns * step : pitch]
            measured = values != 0
            if image.invalid_value:
                measured &= values != image.invalid_value
            if total is None:  # sums of up to 255 pixels in 8 bits, of 65535 16-bit depths in 32 bits
                total = np.where(measured, values, 0).astype(np.uint32 if step <= 256 else np.uint64)
                count = measured.astype(np.uint8 if step <= 15 else np.uint32)
            else:
                total += np.where(measured, values, 0)
                count += measured
            if max_spread > 0 and step > 1:  # unmeasured pixels count neither as low nor as high
                low = _fold(low, np.where(measured, values, np.iinfo(np.uint16).max), np.minimum)
                high = _fold(high, np.where(measured, values, 0), np.maximum)
    index = np.flatnonzero(count)
    z = total.ravel()[index] / count.ravel()[index] * image.scale
    keep = (z >= min_range) & (z <= max_range)
    if low is not None:
        spread = (high.ravel()[index].astype(np.float64) - low.ravel()[index]) * image.scale
        keep &= spread <= max_spread * z
    index, z = index[keep], z[keep]
    v, u = np.divmod(index, total.shape[1])
    intrinsics, centre = image.intrinsics, (step - 1) / 2
    fx, fy, cx, cy = intrinsics[0, 0], intrinsics[1, 1], intrinsics[0, 2], intrinsics[1, 2]
    points = np.empty((len(z), 3))
    points[:, 0] = ((np.arange(total.shape[1]) * pitch + centre - cx) / fx)[u] * z
    points[:, 1] = ((np.arange(total.shape[0]) * pitch + centre - cy) / fy)[v] * z
    points[:, 2] = z
    return points


def _fold(so_far: np.ndarray | None, values: np.ndarray, combine) -> np.ndarray:
    return values.astype(np.uint16) if so_far is None else combine(so_far, values)
