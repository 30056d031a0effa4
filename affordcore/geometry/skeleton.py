"""Virtual skeletons: one file per affordance, 15 joints in the skeleton frame (torso at the origin, facing
+x, z up).

The affordance types are whatever skeleton files exist: the package's own (``affordcore/data/skeletons``)
and any folder in ``settings.skeleton_dirs`` (a user file overrides a built-in one of the same name). Nothing
in the code lists the types.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..jsonfile import read_json

# OpenNI / CAD-60 order (DESIGN.md)
JOINTS = (
    "HEAD",
    "NECK",
    "TORSO",
    "L_SHOULDER",
    "L_ELBOW",
    "R_SHOULDER",
    "R_ELBOW",
    "L_HIP",
    "L_KNEE",
    "R_HIP",
    "R_KNEE",
    "L_HAND",
    "R_HAND",
    "L_FOOT",
    "R_FOOT",
)
BONES = (
    ("HEAD", "NECK"),
    ("NECK", "TORSO"),
    ("NECK", "L_SHOULDER"),
    ("L_SHOULDER", "L_ELBOW"),
    ("L_ELBOW", "L_HAND"),
    ("NECK", "R_SHOULDER"),
    ("R_SHOULDER", "R_ELBOW"),
    ("R_ELBOW", "R_HAND"),
    ("TORSO", "L_HIP"),
    ("L_HIP", "L_KNEE"),
    ("L_KNEE", "L_FOOT"),
    ("TORSO", "R_HIP"),
    ("R_HIP", "R_KNEE"),
    ("R_KNEE", "R_FOOT"),
    ("L_HIP", "R_HIP"),
)
BONE_ENDS = np.array([[JOINTS.index(a), JOINTS.index(b)] for a, b in BONES])  # (bones, 2) joint indices

FORMAT = "affordance-skeleton/1"
BUILTIN_DIR = Path(__file__).parents[1] / "data" / "skeletons"
_FLOOR_SLACK = 0.05  # a joint may dip this far under the floor (ankle markers sit a little above it)


class SkeletonError(ValueError):
    """A skeleton file that cannot be used, or an affordance with no skeleton."""


@dataclass(frozen=True)
class Skeleton:
    affordance: str
    joints: np.ndarray  # (15, 3), skeleton frame
    torso_height: float  # torso above the floor when the affordance is in use (m)
    description: str = ""
    source: str = ""
    # The pose grid also tries torso heights up to this far above torso_height (m, whole voxel steps beyond
    # the usual levels): a person on a high chair or bar stool sits 0.2-0.35 m higher than on a desk chair.
    # 0 (files without the field, models that do not record it): the grid of DESIGN.md, unchanged.
    torso_reach_above: float = 0.0

    @property
    def portable_source(self) -> str:
        """`source` as a model file records it: a built-in skeleton's file named from the package, since a
        shipped model must not hold the path of the checkout that trained it; any other file as it is."""
        path = Path(self.source)
        if path.is_absolute() and path.parent == BUILTIN_DIR:
            return path.relative_to(BUILTIN_DIR.parents[2]).as_posix()
        return self.source

    def placed(self, x: float, y: float, z: float, theta: float) -> np.ndarray:
        """Joints in the world for one pose: [x, y, z] + R_z(theta) H."""
        return place_joints(self.joints, np.array([[x, y, z, theta]]))[0]


def rotation_z(theta: np.ndarray | float) -> np.ndarray:
    """R_z(theta), shape (..., 3, 3)."""
    c, s = np.cos(theta), np.sin(theta)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack(
        [np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, one], -1)], -2
    )


def place_joints(joints: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """World joints (n, J, 3) for poses (n, 4) = (x, y, z, theta)."""
    poses = np.asarray(poses, dtype=np.float64)
    rotated = np.einsum("nij,kj->nki", rotation_z(poses[:, 3]), joints)
    return rotated + poses[:, None, :3]


def load_skeleton(path: str | Path) -> Skeleton:
    """Read and validate one skeleton file; errors name the file and the field."""
    path = Path(path)
    document = read_json(path, SkeletonError)
    if not isinstance(document, dict) or document.get("format") != FORMAT:
        found = document.get("format") if isinstance(document, dict) else None
        raise SkeletonError(f"{path}: 'format' must be {FORMAT!r}, got {found!r}")
    name = document.get("affordance")
    if not isinstance(name, str) or not name:
        raise SkeletonError(f"{path}: 'affordance' must be a non-empty name")
    joints = document.get("joints")
    if not isinstance(joints, dict) or set(joints) != set(JOINTS):
        have = sorted(joints) if isinstance(joints, dict) else joints
        raise SkeletonError(
            f"{path}: 'joints' must map exactly the 15 joints {', '.join(JOINTS)}; got {have}"
        )
    try:
        array = np.array([joints[j] for j in JOINTS], dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise SkeletonError(f"{path}: every joint must be [x, y, z] numbers ({error})") from error
    if array.shape != (15, 3) or not np.isfinite(array).all():
        raise SkeletonError(f"{path}: every joint must be 3 finite numbers")
    if np.linalg.norm(array[JOINTS.index("TORSO")]) > 1e-6:
        raise SkeletonError(
            f"{path}: 'TORSO' must be at the origin of the skeleton frame, is at {array[2].tolist()}"
        )
    torso_height = document.get("torso_height")
    if not isinstance(torso_height, (int, float)) or not torso_height > 0:
        raise SkeletonError(f"{path}: 'torso_height' must be a positive number of metres")
    if torso_height + array[:, 2].min() < -_FLOOR_SLACK:
        lowest = JOINTS[int(array[:, 2].argmin())]
        raise SkeletonError(
            f"{path}: {lowest} would be {-(torso_height + array[:, 2].min()):.2f} m under the floor at "
            f"torso_height {torso_height}"
        )
    reach_above = document.get("torso_reach_above", 0.0)
    if not isinstance(reach_above, (int, float)) or not 0 <= reach_above <= 1.0:
        raise SkeletonError(f"{path}: 'torso_reach_above' must be 0 to 1 m, got {reach_above!r}")
    description, source = str(document.get("description", "")), str(path)
    return Skeleton(name, array, float(torso_height), description, source, float(reach_above))


def skeleton_files(extra_dirs: list[Path] | tuple[Path, ...] = ()) -> dict[str, Path]:
    """Affordance name -> skeleton file, the built-in folder first, then each extra folder overriding it."""
    found: dict[str, Path] = {}
    for folder in (BUILTIN_DIR, *map(Path, extra_dirs)):
        if not folder.is_dir():
            raise SkeletonError(f"{folder}: skeleton folder does not exist")
        for path in sorted(folder.glob("*.json")):
            found[path.stem] = path
    return found


def get_skeleton(name: str, extra_dirs: list[Path] | tuple[Path, ...] = ()) -> Skeleton:
    files = skeleton_files(extra_dirs)
    if name not in files:
        raise SkeletonError(f"unknown affordance {name!r}; known: {', '.join(sorted(files)) or 'none'}")
    skeleton = load_skeleton(files[name])
    if skeleton.affordance != name:
        raise SkeletonError(
            f"{files[name]}: file name says {name!r} but 'affordance' says {skeleton.affordance!r}"
        )
    return skeleton


def all_skeletons(extra_dirs: list[Path] | tuple[Path, ...] = ()) -> list[Skeleton]:
    return [get_skeleton(name, extra_dirs) for name in sorted(skeleton_files(extra_dirs))]
