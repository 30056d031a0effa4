"""Registration weighted by the robot's odometry: point-to-plane ICP with the odometry's motion as a prior.

KISS-ICP registers point to point and takes no prior: where a frame sees flat walls and floor, nothing pins
the sensor along them, and its correspondences to the samples of a flat surface pull it along consistently,
further than the odometry it started from would have strayed. Here each registration point is
matched to the plane of its nearest local-map points, and the odometry's motion since the last frame enters
as a Gaussian prior: the geometry decides the directions it constrains, the odometry the ones it does not
(docs/services.md, "Odometry as a prior", has the measurements). No library at hand does this: KISS-ICP's,
Open3D's and small_gicp's registrations take no prior.

The perturbation is taken about the sensor's own position, so a rotation does not move it and the prior's
translation and rotation are the odometry's own.
"""

from __future__ import annotations

import numpy as np

# the local map's k-d tree is rebuilt every this many frames: a frame adds little to the map, and the tree
# costs more to build than the registration that uses it (docs/services.md)
REBUILD_EVERY = 3
NEIGHBOURS = 8  # local-map points a plane is fitted to
PLANAR = 0.2  # a fit is a plane when its smallest spread is under this share of the middle one
ASSOCIATIONS = 3  # rounds of matching to planes ...
STEPS = 2  # ... and Gauss-Newton steps on each round's planes


class LocalPlanes:
    """KISS-ICP's local map as a k-d tree for plane fits, rebuilt every `REBUILD_EVERY` frames."""

    def __init__(self):
        self._points = np.empty((0, 3))
        self._tree = None
        self._built_at = -REBUILD_EVERY

    def refresh(self, local_map, frame: int) -> None:
        """Rebuild from `local_map` (KISS-ICP's VoxelHashMap) when `frame` is `REBUILD_EVERY` past the
        last build (or the map was never read)."""
        from scipy.spatial import cKDTree

        if self._tree is not None and 0 <= frame - self._built_at < REBUILD_EVERY:
            return
        self._points = np.asarray(local_map.point_cloud(), dtype=np.float64).reshape(-1, 3)
        # unbalanced, not compacted: half the build time; queries of a few thousand points hardly slower
        self._tree = (
            cKDTree(self._points, balanced_tree=False, compact_nodes=False) if len(self._points) else None
        )
        self._built_at = frame

    def forget(self) -> None:
        """Drop the tree (the local map was replaced, as after a restore)."""
        self.__init__()

    def planes(self, points: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(which of `points` have a plane within `reach`, the planes' centroids, their unit normals)."""
        if self._tree is None or len(self._points) < NEIGHBOURS:
            return np.zeros(len(points), bool), np.empty((0, 3)), np.empty((0, 3))
        distances, index = self._tree.query(points, k=NEIGHBOURS, distance_upper_bound=reach)
        matched = np.isfinite(distances).all(axis=1)
        neighbours = self._points[index[matched]]
        centroids = neighbours.mean(axis=1)
        spread = neighbours - centroids[:, None]
        values, vectors = np.linalg.eigh(np.einsum("mki,mkj->mij", spread, spread))
        planar = values[:, 0] < PLANAR * values[:, 1]
        matched[matched] = planar
        return matched, centroids[planar], vectors[planar, :, 0]


def odometry_information(step: np.ndarray, share: float, least: float, least_turn_deg: float) -> np.ndarray:
    """The prior's 6 x 6 information (rotation, then translation) for an odometry step (4 x 4): its error
    is taken as `share` of the step's length (at least `least` m) and of its turn (at least `least_turn_deg`),
    one standard deviation per axis."""
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_matrix(step[:3, :3]).magnitude()
    translation = max(share * float(np.linalg.norm(step[:3, 3])), least)
    rotation = max(share * turn, np.radians(least_turn_deg))
    return np.diag([rotation**-2] * 3 + [translation**-2] * 3)


def align_with_prior(
    source: np.ndarray,
    prior: np.ndarray,
    information: np.ndarray,
    planes: LocalPlanes,
    reach: float,
    noise: float,
) -> np.ndarray:
    """The pose (4 x 4) that best puts `source` (sensor frame) on the local map's planes and agrees with the
    odometry's `prior` pose, weighted by `information` against a point-to-plane residual of `noise` (m, one
    standard deviation, also the Cauchy kernel's scale). Starts at the prior; planes within `reach`."""
    from scipy.spatial.transform import Rotation

    pose = prior.copy()
    for _ in range(ASSOCIATIONS):
        moved = source @ pose[:3, :3].T + pose[:3, 3]
        matched, centroids, normals = planes.planes(moved, reach)
        points = source[matched]
        for _ in range(STEPS):
            world = points @ pose[:3, :3].T + pose[:3, 3]
            residual = np.einsum("ij,ij->i", world - centroids, normals)
            jacobian = np.hstack([np.cross(world - pose[:3, 3], normals), normals])
            weight = 1.0 / ((1.0 + (residual / noise) ** 2) * noise**2)
            hessian = jacobian.T @ (jacobian * weight[:, None])
            gradient = jacobian.T @ (weight * residual)
            towards_prior = np.concatenate(
                [Rotation.from_matrix(prior[:3, :3] @ pose[:3, :3].T).as_rotvec(), prior[:3, 3] - pose[:3, 3]]
            )
            step = np.linalg.solve(hessian + information, information @ towards_prior - gradient)
            pose[:3, :3] = Rotation.from_rotvec(step[:3]).as_matrix() @ pose[:3, :3]
            pose[:3, 3] += step[3:]
    return pose
