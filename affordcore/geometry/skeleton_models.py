"""Skeleton models from real Kinect skeletons, the paper's way: filter, canonicalise, K-means, take a medoid.

The recipe is data (``affordcore/data/skeleton_sources.json``): per affordance, the trial (posture) and
actions of MSR DailyActivity3D whose frames describe it, and optionally the height its hands must reach. The
data set is read in place (research-use terms: never copied). ``derive`` returns the models and the numbers
behind them; ``write_skeleton`` turns them into the package's files (``plots.plot_skeletons`` draws them).
See docs/skeletons.md.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .skeleton import BONE_ENDS, BONES, FORMAT, JOINTS, Skeleton, rotation_z

SOURCES = Path(__file__).parents[1] / "data" / "skeleton_sources.json"
SOURCES_FORMAT = "affordance-skeleton-sources/1"
FRAME = "skeleton frame: torso at the origin, facing +x, z up, metres"
K_MAX = 8  # K-means K candidates 2..K_MAX, and at most a third of the recordings (see ``cluster``)
SEED = 0
BONE_BAND = (0.7, 1.4)  # each bone within this ratio of the subject's median length
SYMMETRY = 1.4  # left/right bones within this ratio of each other
TWIST_DEG = 45.0  # hip and shoulder left-right axes within this angle of each other (in plan)
MIN_SHARE = 0.10  # a recipe's "choose" rule only considers clusters holding at least this share of its frames

_J = {name: i for i, name in enumerate(JOINTS)}
_PAIRS = [  # (left bone, right bone) indices into BONES
    (BONES.index(bone), BONES.index(tuple(j.replace("L_", "R_") for j in bone)))
    for bone in BONES
    if any(j.startswith("L_") for j in bone) and "R_HIP" not in bone
]


def _tree(root: str = "TORSO") -> list[tuple[int, int, int]]:
    """(parent joint, child joint, bone index) outward from the torso, breadth first (the hip-hip bone closes
    a loop and is left out)."""
    edges, seen, frontier = [], {root}, [root]
    while frontier:
        parent = frontier.pop(0)
        for i, bone in enumerate(BONES):
            if parent in bone and (child := bone[1 - bone.index(parent)]) not in seen:
                seen.add(child)
                frontier.append(child)
                edges.append((_J[parent], _J[child], i))
    return edges


_TREE = _tree()


@dataclass(frozen=True)
class Frames:
    """Skeleton frames, ``joints`` (n, 15, 3), with one label of each kind per frame."""

    joints: np.ndarray
    sequence: np.ndarray  # e.g. 'a09_s03_e01'
    index: np.ndarray  # frame number in its sequence
    action: np.ndarray
    subject: np.ndarray
    trial: np.ndarray  # 'e01', 'e02'
    scale: np.ndarray  # the factor the joints were scaled by

    def __len__(self) -> int:
        return len(self.joints)

    def take(self, mask: np.ndarray) -> Frames:
        return Frames(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))

    def with_joints(self, joints: np.ndarray) -> Frames:
        return replace(self, joints=joints)

    def with_scale(self, factor: np.ndarray) -> Frames:
        return replace(self, joints=self.joints * factor[:, None, None], scale=self.scale * factor)

    def select(self, trial: str, actions: list[str]) -> np.ndarray:
        return (self.trial == trial) & np.isin(self.action, actions)


@dataclass
class Derivation:
    """Everything ``derive`` decided, for the files, the report and the figure."""

    skeletons: list[Skeleton]
    filters: dict[str, dict[str, int]]  # row -> group -> frames: 'loaded', removed by each filter, 'kept'
    clusters: dict[str, dict]  # affordance -> frames, K, silhouettes, sizes, chosen, medoid, forearm_turns
    scale: dict[str, float]  # spans, factors, and how many standing frames the body came from
    members: dict[str, np.ndarray] = field(repr=False)  # affordance -> its cluster's frames, skeleton frame


def load_sources(path: str | Path = SOURCES) -> dict:
    """The recipe: the data set's trials (posture and leg-angle bands), the adult scale, and per affordance
    the trial, the actions, and optionally a cluster-choice rule ("choose") and a hand height
    ("hands_height")."""
    sources = json.loads(Path(path).read_text())
    if sources.get("format") != SOURCES_FORMAT:
        raise ValueError(f"{path}: 'format' must be {SOURCES_FORMAT!r}")
    return sources


def default_data_path(sources: dict | None = None) -> Path:
    """The shared data set beside the project: <root>/shared/data/<data_file> (the project is <root>/main)."""
    sources = sources or load_sources()
    return Path(__file__).resolve().parents[3] / "shared" / "data" / sources["data_file"]


def load_frames(path: str | Path, actions: set[str], trials: set[str]) -> Frames:
    """The 15-joint frames of the sequences with these actions and trials (Kinect camera frame, y up)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: skeleton data set not found (see ../shared/data/README.md)")
    with np.load(path) as data:
        meta = data["meta"]
        rows = [r for r in meta if r["action"] in actions and f"e{r['trial']:02d}" in trials]
        if not rows:
            raise ValueError(
                f"{path}: no sequences with actions {sorted(actions)} in trials {sorted(trials)}"
            )
        joints = [data[f"{r['key']}_j15"].astype(np.float64) for r in rows]
    lengths = [len(j) for j in joints]

    def repeat(values):
        return np.repeat(np.array(values), lengths)

    return Frames(
        np.concatenate(joints),
        repeat([r["key"] for r in rows]),
        np.concatenate([np.arange(n) for n in lengths]),
        repeat([r["action"] for r in rows]),
        repeat([int(r["subject"]) for r in rows]),
        repeat([f"e{r['trial']:02d}" for r in rows]),
        np.ones(sum(lengths)),
    )


def kinect_to_zup(joints: np.ndarray) -> np.ndarray:
    """Kinect camera frame (x, y up, z depth) to z up by a proper rotation: (x, y, z) -> (x, -z, y)."""
    return np.stack([joints[..., 0], -joints[..., 2], joints[..., 1]], axis=-1)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _plan_axes(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit right-to-left axes of the hips and of the shoulders, in plan (z dropped)."""
    hips = joints[:, _J["L_HIP"], :2] - joints[:, _J["R_HIP"], :2]
    shoulders = joints[:, _J["L_SHOULDER"], :2] - joints[:, _J["R_SHOULDER"], :2]
    return _unit(hips), _unit(shoulders)


def canonicalise(joints: np.ndarray) -> np.ndarray:
    """z-up frames (n, 15, 3) to the skeleton frame: torso at the origin, the person's left (mean of the hip
    and shoulder right-to-left axes, in plan) along +y, so facing +x. Only yaw is removed; any lean stays."""
    centred = joints - joints[:, [_J["TORSO"]]]
    left = sum(_plan_axes(centred))
    heading = np.arctan2(left[:, 1], left[:, 0]) - np.pi / 2  # facing = left turned -90 degrees
    return np.einsum("nij,nkj->nki", rotation_z(-heading), centred)


def _angle_deg(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    cosine = np.sum(_unit(u) * _unit(v), axis=-1)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def leg_angles(joints: np.ndarray) -> dict[str, np.ndarray]:
    """Per frame and side (n, 2), in degrees, of canonical frames: 'thigh' hip-to-knee from straight down,
    signed in the sagittal plane (positive = knee forward, over 90 = knee above hip); 'knee' the inner angle
    hip-knee-foot (180 = straight); 'hip' the angle between the trunk (torso to neck) and the thigh (180 =
    standing straight, 90 = seated upright)."""

    def side(s):
        hip, knee, foot = (joints[:, _J[f"{s}_{j}"]] for j in ("HIP", "KNEE", "FOOT"))
        thigh = knee - hip
        trunk = joints[:, _J["NECK"]] - joints[:, _J["TORSO"]]
        return {
            "thigh": np.degrees(np.arctan2(thigh[:, 0], -thigh[:, 2])),
            "knee": _angle_deg(hip - knee, foot - knee),
            "hip": _angle_deg(trunk, thigh),
        }

    left, right = side("L"), side("R")
    return {name: np.stack([left[name], right[name]], axis=1) for name in left}


def bone_lengths(joints: np.ndarray) -> np.ndarray:
    """(n, 15, 3) -> (n, len(BONES)) metres."""
    return np.linalg.norm(joints[:, BONE_ENDS[:, 0]] - joints[:, BONE_ENDS[:, 1]], axis=-1)


def filter_masks(frames: Frames, trials: dict) -> dict[str, np.ndarray]:
    """Per filter, which frames pass it (z-up or canonical joints; NaN fails every test). Bone lengths are
    compared with each subject's median over the frames that have all joints; angles with the trial's
    bands."""
    complete = np.isfinite(frames.joints).all(axis=(1, 2)) & ~(frames.joints == 0).all(axis=2).any(axis=1)
    joints = np.where(complete[:, None, None], frames.joints, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        lengths = bone_lengths(joints)
        ratio = np.full_like(lengths, np.nan)
        for subject in np.unique(frames.subject[complete]):
            mine = frames.subject == subject
            ratio[mine] = lengths[mine] / np.median(lengths[mine & complete], axis=0)
        bones = ((ratio >= BONE_BAND[0]) & (ratio <= BONE_BAND[1])).all(axis=1)
        left, right = np.array(_PAIRS).T
        pair_ratio = lengths[:, left] / lengths[:, right]
        twist = _angle_deg(*_plan_axes(joints))
        symmetric = ((pair_ratio <= SYMMETRY) & (pair_ratio >= 1 / SYMMETRY)).all(axis=1) & (
            twist <= TWIST_DEG
        )
        angles = leg_angles(canonicalise(joints))
    posture = np.zeros(len(frames), dtype=bool)
    for trial, bands in trials.items():
        ok = frames.trial == trial
        for name, values in angles.items():
            low, high = bands[f"{name}_deg"]
            ok &= ((values >= low) & (values <= high)).all(axis=1)
        posture |= ok
    return {
        "missing joints": complete,
        "bone lengths": bones,
        "left/right symmetry": symmetric,
        "leg angles": posture,
    }


def subject_scales(frames: Frames, spec: dict) -> tuple[dict[int, float], float, float]:
    """Per subject, the factor that makes the median standing head-to-foot span (canonical z) that of an adult
    of ``stature``; also that target span and the all-subject median span (the global factor is their
    ratio)."""
    target = spec["stature"] - spec["head_centre_below_top"] - spec["foot_joint_above_floor"]
    standing = frames.take(frames.trial == spec["trial"])
    feet = standing.joints[:, [_J["L_FOOT"], _J["R_FOOT"]], 2].mean(axis=1)
    span = standing.joints[:, _J["HEAD"], 2] - feet
    missing = sorted(set(frames.subject.tolist()) - set(standing.subject.tolist()))
    if missing:
        raise ValueError(f"subjects {missing} have no {spec['trial']} frames left to scale them by")
    scales = {
        int(s): target / float(np.median(span[standing.subject == s])) for s in np.unique(frames.subject)
    }
    return scales, target, float(np.median(span))


def cluster(features: np.ndarray, recordings: int, seed: int = SEED):
    """K-means (n_init 10, fixed seed) for K = 2 .. min(K_MAX, recordings // 3); the K with the best
    silhouette wins. The cap keeps about three recordings per cluster: consecutive frames of one recording are
    near copies, so with more clusters than that K-means separates recordings rather than poses (the
    silhouette then keeps rising with K). One thread: the same sums in the same order on every machine, and no
    OpenMP spin-waiting on a busy one. Returns the fitted winner and the silhouette of every K."""
    from sklearn.cluster import KMeans
    from sklearn.metrics import silhouette_score
    from threadpoolctl import threadpool_limits

    k_range = range(2, max(2, min(K_MAX, recordings // 3)) + 1)
    with threadpool_limits(1):
        fits = {k: KMeans(n_clusters=k, n_init=10, random_state=seed).fit(features) for k in k_range}
    scores = {k: float(silhouette_score(features, fit.labels_)) for k, fit in fits.items()}
    return fits[max(scores, key=scores.get)], scores


def trunk_lean_deg(joints: np.ndarray) -> np.ndarray:
    """Lean of the trunk (torso to neck) from vertical in the sagittal plane, degrees, forward positive."""
    trunk = joints[..., _J["NECK"], :] - joints[..., _J["TORSO"], :]
    return np.degrees(np.arctan2(trunk[..., 0], trunk[..., 2]))


def hands_height(joints: np.ndarray, foot_clearance: float) -> np.ndarray:
    """Height of the hands (mean of the two) above the floor, with the lower foot joint ``foot_clearance``
    up."""
    feet = joints[..., [_J["L_FOOT"], _J["R_FOOT"]], 2].min(axis=-1)
    return joints[..., [_J["L_HAND"], _J["R_HAND"]], 2].mean(axis=-1) - feet + foot_clearance


MEASURES = {"trunk_lean_deg": trunk_lean_deg}  # pose measures a recipe's "choose" rule may name


def choose_cluster(centres: np.ndarray, sizes: np.ndarray, recipe: dict, foot_clearance: float) -> int:
    """Which cluster (centres (K, 15, 3)) stands for a recipe. With "hands_height": the one whose hands are
    closest to that height; with a rule such as "choose": {"lowest": "trunk_lean_deg"}: the one with the
    lowest (highest) measure; both among the clusters holding at least MIN_SHARE of the frames. Otherwise the
    largest."""
    candidates = np.flatnonzero(sizes >= MIN_SHARE * sizes.sum())
    if "hands_height" in recipe:
        score = np.abs(hands_height(centres, foot_clearance) - recipe["hands_height"])
    elif "choose" in recipe:
        ((order, measure),) = recipe["choose"].items()
        score = MEASURES[measure](centres) * {"lowest": 1, "highest": -1}[order]
    else:
        return int(np.argmax(sizes))
    return int(candidates[np.argmin(score[candidates])])


def medoid(features: np.ndarray, labels: np.ndarray, centre: np.ndarray, label: int) -> int:
    """Index of the real frame of cluster ``label`` closest to its centre."""
    members = np.flatnonzero(labels == label)
    return int(members[np.argmin(np.linalg.norm(features[members] - centre, axis=1))])


def body_lengths(joints: np.ndarray) -> np.ndarray:
    """One adult body: the median length of every bone over these frames, left and right averaged."""
    lengths = np.median(bone_lengths(joints), axis=0)
    for left, right in _PAIRS:
        lengths[[left, right]] = lengths[[left, right]].mean()
    return lengths


def retarget(joints: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The pose of one frame (15, 3), its bone directions, on the body ``lengths``, the torso staying put."""
    out = joints.copy()
    for parent, child, bone in _TREE:
        out[child] = out[parent] + lengths[bone] * _unit(joints[child] - joints[parent])
    return out


def reach(joints: np.ndarray, height: float) -> tuple[np.ndarray, list[float]]:
    """Turn each forearm about its elbow, in the vertical plane of its own heading (straight ahead, +x, if it
    does not point forward), so the hand is at ``height`` (skeleton frame) in front of the elbow. Bone lengths
    and all other joints are kept. Returns the joints and each forearm's turn in degrees (left, right)."""
    out, turns = joints.copy(), []
    for side in "LR":
        elbow, hand = joints[_J[f"{side}_ELBOW"]], _J[f"{side}_HAND"]
        forearm = joints[hand] - elbow
        length, drop = float(np.linalg.norm(forearm)), height - elbow[2]
        if abs(drop) > length:
            raise ValueError(
                f"the {side} hand cannot reach {height:+.2f} m from its elbow at {elbow[2]:+.2f} m"
            )
        heading = _unit(forearm[:2]) if forearm[0] > 1e-6 else np.array([1.0, 0.0])
        out[hand] = elbow + np.append(heading * np.sqrt(length**2 - drop**2), drop)
        turns.append(float(_angle_deg(forearm, out[hand] - elbow)))
    return out, turns


def filter_frames(frames: Frames, sources: dict) -> tuple[Frames, dict[str, dict[str, int]]]:
    """The frames that pass every filter, and a table: filter -> group -> frames it removed, the filters
    applied in order (a frame counts against the first it fails), with 'loaded' and 'kept' rows. Groups: all
    loaded frames and each affordance's frames."""
    groups = {"all": np.ones(len(frames), bool)}
    groups |= {name: frames.select(r["trial"], r["actions"]) for name, r in sources["affordances"].items()}
    kept = np.ones(len(frames), dtype=bool)
    table = {"loaded": {g: int(m.sum()) for g, m in groups.items()}}
    for name, passes in filter_masks(frames, sources["trials"]).items():
        table[name] = {g: int((m & kept & ~passes).sum()) for g, m in groups.items()}
        kept &= passes
    table["kept"] = {g: int((m & kept).sum()) for g, m in groups.items()}
    return frames.take(kept), table


def _model(name: str, recipe: dict, group: Frames, body: np.ndarray, sources: dict, body_note: str):
    """Cluster one affordance's frames, choose a cluster, and put its medoid's pose on the adult body, feet on
    the floor. Returns the skeleton, the numbers, and the chosen cluster's frames."""
    features = group.joints.reshape(len(group), -1)
    fit, scores = cluster(features, len(np.unique(group.sequence)))
    sizes = np.bincount(fit.labels_, minlength=fit.n_clusters)
    clearance = sources["scale"]["foot_joint_above_floor"]
    chosen = choose_cluster(fit.cluster_centers_.reshape(-1, 15, 3), sizes, recipe, clearance)
    pick = medoid(features, fit.labels_, fit.cluster_centers_[chosen], chosen)
    joints = retarget(group.joints[pick], body)
    torso_height = clearance - joints[[_J["L_FOOT"], _J["R_FOOT"]], 2].min()
    adapted, turns = "", []
    if "hands_height" in recipe:
        before = hands_height(joints, clearance)
        joints, turns = reach(joints, recipe["hands_height"] - torso_height)
        adapted = (
            f"; the cluster with its hands closest to {recipe['hands_height']:.2f} m (the medoid's at "
            f"{before:.2f} m), adapted: forearms turned about the elbows by {turns[0]:.0f} and "
            f"{turns[1]:.0f} degrees (left, right) to put both hands at {recipe['hands_height']:.2f} m, "
            "bone lengths kept"
        )
    frame = f"frame {group.index[pick]} of {group.sequence[pick]}"
    source = (
        f"{sources['dataset']}, trial {recipe['trial']} ({', '.join(recipe['actions'])}): the pose (bone "
        f"directions) of {frame}, the medoid of K-means cluster {chosen} ({sizes[chosen]} of {len(group)} "
        f"filtered frames; K={fit.n_clusters} by silhouette), on {body_note}{adapted}"
    )
    info = {
        "frames": len(group),
        "k": fit.n_clusters,
        "silhouettes": scores,
        "sizes": sizes.tolist(),
        "chosen": chosen,
        "medoid": frame,
        "forearm_turns": turns,
    }
    reach_above = float(recipe.get("torso_reach_above", 0.0))  # torso levels above the usual (high seats)
    skeleton = Skeleton(name, joints, float(torso_height), recipe["description"], source, reach_above)
    return skeleton, info, group.joints[fit.labels_ == chosen]


def derive(data_path: str | Path | None = None, sources: dict | None = None) -> Derivation:
    """Derive one skeleton per affordance of the recipe from the real frames (deterministic)."""
    sources = sources or load_sources()
    recipes, spec = sources["affordances"], sources["scale"]
    frames = load_frames(
        data_path or default_data_path(sources),
        {a for r in recipes.values() for a in r["actions"]},
        set(sources["trials"]),
    )
    frames, table = filter_frames(frames.with_joints(kinect_to_zup(frames.joints)), sources)
    frames = frames.with_joints(canonicalise(frames.joints))
    scales, target, median_span = subject_scales(frames, spec)
    frames = frames.with_scale(np.array([scales[s] for s in frames.subject.tolist()]))
    standing = frames.trial == spec["trial"]
    body = body_lengths(frames.joints[standing])
    scale = {
        "target_span": target,
        "median_span": median_span,
        "factor": target / median_span,
        "subject_min": min(scales.values()),
        "subject_max": max(scales.values()),
        "body_frames": int(standing.sum()),
    }
    body_note = (
        f"a {spec['stature']:.2f} m adult body (median bone lengths of the {scale['body_frames']} filtered "
        f"{spec['trial']} frames, each subject scaled to a head-to-foot span of {target:.2f} m: "
        f"x{scale['subject_min']:.3f} to x{scale['subject_max']:.3f}, x{scale['factor']:.3f} at the median)"
    )

    skeletons, clusters, members = [], {}, {}
    for name, recipe in recipes.items():
        group = frames.take(frames.select(recipe["trial"], recipe["actions"]))
        skeleton, clusters[name], members[name] = _model(name, recipe, group, body, sources, body_note)
        skeletons.append(skeleton)
    return Derivation(skeletons, table, clusters, scale, members)


def skeleton_json(skeleton: Skeleton) -> str:
    """The file text of one skeleton, one joint per line, millimetre rounding."""
    header = {
        "format": FORMAT,
        "affordance": skeleton.affordance,
        "description": skeleton.description,
        "frame": FRAME,
        "torso_height": round(skeleton.torso_height, 3),
        "source": skeleton.source,
    }
    if skeleton.torso_reach_above:  # only skeletons that have it: the other files stay as they were
        header["torso_reach_above"] = round(skeleton.torso_reach_above, 3)
    rows = [
        f'  "{name}": [{", ".join(f"{round(v, 3) + 0.0:.3f}" for v in xyz)}]'
        for name, xyz in zip(JOINTS, skeleton.joints)
    ]
    return json.dumps(header, indent=1)[:-2] + ',\n "joints": {\n' + ",\n".join(rows) + "\n }\n}\n"


def write_skeleton(skeleton: Skeleton, folder: str | Path) -> Path:
    path = Path(folder) / f"{skeleton.affordance}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(skeleton_json(skeleton))
    return path
