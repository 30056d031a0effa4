"""Model files: one classifier per affordance, versioned and self-describing (JSON), and the default models
the package ships (`shipped_models`, `choose_models`).

A model says what it was trained for and on: the affordance and its skeleton, the feature layout (with the
fingerprint of `FeatureLayout.describe()`), the pose grid's resolution, the learner and its parameters, the
weights, bias and threshold, the training rooms with their class counts, and validation metrics. A cascade
(`learn/cascade.py`) also holds its second stage: the fraction of poses it rescores and its trees as node
tables (data, never pickled code); `place_threshold` is the score a skeleton-map place must beat, counted from
the median of the room's candidate scores when `place_reference` is "room-median", and never below
`place_floor` when the model has one; a model with a `place_model` (affordcore/mapping/places.py) gives every
candidate place a calibrated probability instead, and the map keeps those above the place model's cut
(`map.place_probability` overrides it).
Loading a model against a feature layout other than its own is a `ModelError`, not a silent wrong answer.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..geometry.features import FeatureLayout
from ..geometry.skeleton import Skeleton
from ..jsonfile import read_json
from ..mapping.places import PlaceModel, room_reference
from .trees import TreeEnsemble

FORMAT = "affordance-model/3"
# /2 added the optional place_threshold, rescorer, place_reference, place_floor; /3 the optional place_model
READABLE = ("affordance-model/1", "affordance-model/2", FORMAT)
PLACE_REFERENCES = (None, "room-median")
MODELS_DIR = Path(__file__).parents[1] / "data" / "models"  # the shipped default models, one per affordance


class ModelError(ValueError):
    """A model file that cannot be used here; the message names the file and the problem."""


KEPT_TEXTS = ("_rescorer_json", "_place_json")  # the id's serialised documents, kept beside the model


def _json(document) -> str:
    return json.dumps(document, sort_keys=True)


@dataclass
class AffordanceModel:
    affordance: str
    layout: dict  # FeatureLayout.describe()
    fingerprint: str
    weights: np.ndarray
    bias: float
    threshold: float
    learner: str
    parameters: dict = field(default_factory=dict)
    skeleton: dict = field(default_factory=dict)  # joints, torso_height, source
    grid: dict = field(default_factory=dict)  # step, theta_step, n_theta, z levels
    training: dict = field(default_factory=dict)  # rooms and class counts
    validation: dict = field(default_factory=dict)  # precision, recall, f1
    place_threshold: float | None = None  # None: the threshold
    # the cascade's second stage: {"fraction", "max_poses", "trees"}, and "local_detail": true when its trees
    # read the fine columns after the features (`inference.second_stage_rows`)
    rescorer: dict | None = None
    # "room-median": place_threshold counts from the median candidate score of the room (room_reference)
    place_reference: str | None = None
    place_floor: float | None = None  # and a place must also beat this absolute score (None: no floor)
    # places.PlaceModel.to_dict(): each place's probability from its evidence; when set, it decides the
    # skeleton map and the score cuts above are kept only as a record
    place_model: dict | None = None

    def __post_init__(self) -> None:
        if self.place_reference not in PLACE_REFERENCES:
            raise ValueError(
                f"place_reference must be one of {PLACE_REFERENCES}, not {self.place_reference!r}"
            )
        if self.rescorer is not None:
            fraction, max_poses = self.rescorer.get("fraction"), self.rescorer.get("max_poses")
            if not isinstance(fraction, (int, float)) or not 0 < fraction <= 1:
                raise ValueError(f"the rescorer's fraction must lie in (0, 1], not {fraction!r}")
            if max_poses is not None and (not isinstance(max_poses, int) or max_poses < 1):
                raise ValueError(
                    f"the rescorer's max_poses must be a positive whole number, not {max_poses!r}"
                )
            if not isinstance(self.rescorer.get("local_detail", False), bool):
                raise ValueError(
                    f"the rescorer's local_detail must be true or false, not "
                    f"{self.rescorer['local_detail']!r}"
                )

    @property
    def id(self) -> str:
        """affordance/learner/hash of the weights: names exactly this model in the maps it makes."""
        # json.dumps([place_threshold, rescorer, floor?, place_model?]) item by item, the same text (ids of
        # models without a floor or a place model unchanged); the documents' texts are kept (`_made_from`):
        # the rescorer's tree nodes take tens of ms to serialise, and every map names its model
        items = [json.dumps(self.place_threshold), self._made_from("_rescorer_json", self.rescorer, _json)]
        items += [] if self.place_floor is None else [json.dumps(self.place_floor)]
        items += [] if self.place_model is None else [self._made_from("_place_json", self.place_model, _json)]
        second = f"[{', '.join(items)}]" + (self.place_reference or "")
        digest = hashlib.sha256(
            np.asarray(self.weights, dtype=np.float64).tobytes()
            + repr((self.bias, self.threshold)).encode()
            + (
                second.encode()
                if self.place_threshold is not None or self.rescorer or self.place_model
                else b""
            )
        )
        return f"{self.affordance}/{self.learner}/{digest.hexdigest()[:12]}"

    def _made_from(self, slot: str, document, make):
        """`make(document)`, made once while the model holds that document (kept with it in `slot`): a model
        given a new one (a refit) answers with the new one's."""
        made = self.__dict__.get(slot)
        if made is None or made[0] is not document:
            made = self.__dict__[slot] = (document, make(document))
        return made[1]

    def __getstate__(self) -> dict:
        """Pickled (to worker processes) without the kept JSON texts (1.3 MB): the fields are the model."""
        return {k: v for k, v in self.__dict__.items() if k not in KEPT_TEXTS}

    def as_skeleton(self) -> Skeleton:
        """The skeleton the model was trained with (maps place it, not whatever skeleton file is installed
        now)."""
        return Skeleton(
            self.affordance,
            np.asarray(self.skeleton["joints"], dtype=np.float64),
            float(self.skeleton["torso_height"]),
            source=self.skeleton.get("source", ""),
            # models that predate the field were trained (and are scored) on DESIGN.md's three levels
            torso_reach_above=float(self.skeleton.get("torso_reach_above", 0.0)),
        )

    def decision(self, X: np.ndarray) -> np.ndarray:
        return X @ self.weights.astype(X.dtype, copy=False) + self.bias

    @property
    def skeleton_threshold(self) -> float:
        """The place threshold: what a place of the skeleton map must beat, counted from the room's
        reference when `place_reference` says so (`place_cut`)."""
        return self.threshold if self.place_threshold is None else self.place_threshold

    def place_cut(self, scores: np.ndarray) -> float:
        """The score a place of this room's skeleton map must beat, given every pose's score in the room."""
        return self.place_cut_from(room_reference(scores) if self.place_reference else 0.0)

    def place_cut_from(self, reference: float) -> float:
        """`place_cut` for a room whose reference (`places.room_reference`) is known."""
        cut = self.skeleton_threshold + (reference if self.place_reference == "room-median" else 0.0)
        return cut if self.place_floor is None else max(cut, self.place_floor)

    @property
    def places(self) -> PlaceModel | None:
        """The place model that gives each candidate place its probability (None: places by score cut). Made
        once per `place_model` document: a model given a new one (a refit) answers with the new one."""
        if not self.place_model:
            return None
        return self._made_from("_places", self.place_model, PlaceModel.from_dict)

    @cached_property
    def trees(self) -> TreeEnsemble | None:
        return TreeEnsemble.from_dict(self.rescorer["trees"]) if self.rescorer else None

    @property
    def local_detail(self) -> bool:
        """Whether the second stage's trees read the fine columns after the features."""
        return bool(self.rescorer and self.rescorer.get("local_detail", False))

    @property
    def second_stage_width(self) -> int:
        """The columns of the rows the trees read: the features, and the fine columns after them."""
        from ..geometry.columns import N_FEATURES

        extra = N_FEATURES if self.local_detail else 0
        return int(self.layout.get("n_features", len(self.weights))) + extra

    def check_layout(self, layout: FeatureLayout, source: str | None = None) -> None:
        """Raise ModelError unless the model's features are the layout's; `source` names the model in the
        message (its `id` when not given, worked out only then: the first id serialises the trees)."""
        if layout.fingerprint != self.fingerprint:
            source = source or f"model {self.id}"
            raise ModelError(
                f"{source}: trained on feature layout {self.fingerprint} ({_summary(self.layout)}), but the "
                f"running code computes {layout.fingerprint} ({_summary(layout.describe())}); retrain it or "
                "set the settings to match"
            )

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        document = {"format": FORMAT, **asdict(self), "weights": [float(v) for v in self.weights]}
        rescorer = document.pop("rescorer")
        text = json.dumps(document, indent=1)
        if rescorer:  # thousands of tree nodes: one compact line rather than one line per number
            text = text[: text.rindex("}")].rstrip() + ',\n "rescorer": ' + json.dumps(rescorer) + "\n}"
        path.write_text(text + "\n")
        return path


class _Strict(BaseModel):
    # a model file is input like any other: numbers are numbers (no "1.5" strings), finite, and no field
    # is unknown (a misspelt one would be ignored silently)
    model_config = ConfigDict(strict=True, extra="forbid", allow_inf_nan=False)


class _Layout(BaseModel):
    model_config = ConfigDict(
        strict=True, extra="allow"
    )  # the rest is FeatureLayout.describe()'s, fingerprinted
    n_features: int = Field(gt=0)


class _Skeleton(_Strict):
    joints: list[Annotated[list[float], Field(min_length=3, max_length=3)]] = Field(
        min_length=15, max_length=15
    )
    torso_height: float = Field(gt=0)
    source: str = ""
    torso_reach_above: float = Field(0.0, ge=0)


class _ModelFile(_Strict):
    """What a model file must hold, type by type (checked before anything is built from it)."""

    format: str
    affordance: str = Field(min_length=1)
    layout: _Layout
    fingerprint: str = Field(min_length=1)
    weights: list[float] = Field(min_length=1)
    bias: float
    threshold: float
    learner: str = Field(min_length=1)
    parameters: dict = {}
    skeleton: _Skeleton
    grid: dict = {}
    training: dict = {}
    validation: dict = {}
    place_threshold: float | None = None
    rescorer: dict | None = None
    place_reference: Literal[PLACE_REFERENCES] | None = None
    place_floor: float | None = None
    place_model: dict | None = None


def _checked(path: Path, document: dict) -> dict:
    """The file's fields, each of its type; a ModelError naming the first field that is not."""
    try:
        checked = _ModelFile.model_validate(document)
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "the file"
        raise ModelError(
            f"{path}: malformed model: {where}: {first['msg']} (got {first.get('input')!r:.60})"
            + (f"; {error.error_count() - 1} more problems" if error.error_count() > 1 else "")
        ) from None
    fields = checked.model_dump(exclude={"format"})
    fields["layout"] = document["layout"]  # as written: its fingerprint is of the whole document
    fields["skeleton"] = document["skeleton"]  # as written (one that predates torso_reach_above keeps none)
    return fields


def load_model(path: str | Path, layout: FeatureLayout | None = None) -> AffordanceModel:
    """Read a model file, every field checked for its type and shape (a ModelError names the one that is
    wrong); with `layout`, refuse a model made for another feature layout."""
    path = Path(path)
    document = read_json(path, ModelError)
    if not isinstance(document, dict) or document.get("format") not in READABLE:
        raise ModelError(
            f"{path}: not an {FORMAT} file (format "
            f"{document.get('format') if isinstance(document, dict) else None!r})"
        )
    fields = _checked(path, document)
    try:
        weights = np.asarray(fields.pop("weights"), dtype=np.float64)
        model = AffordanceModel(weights=weights, **fields)
        _ = model.trees, model.places  # a malformed second stage fails here, not in the middle of a map
    except (KeyError, TypeError, ValueError) as error:
        raise ModelError(f"{path}: malformed model ({error})") from error
    if len(model.weights) != model.layout.get("n_features"):
        raise ModelError(
            f"{path}: {len(model.weights)} weights for a layout of {model.layout.get('n_features')} features"
        )
    if model.trees is not None and model.trees.n_features_used > model.second_stage_width:
        # the trees' kernel reads rows unchecked: a split past the row's end would read beyond it
        raise ModelError(
            f"{path}: the trees split on feature {model.trees.n_features_used - 1}; the second stage's rows "
            f"have {model.second_stage_width}"
        )
    if layout is not None:
        model.check_layout(layout, str(path))
    return model


def _summary(layout: dict) -> str:
    return (
        f"v{layout.get('version')}, {layout.get('n_features')} features, {layout.get('cell_size')} m cells, "
        f"{layout.get('voxel_resolution')} m voxels"
    )


def models_in(folder: Path) -> dict[str, Path]:
    """{affordance: model file} of the `<affordance>.model.json` files in `folder`."""
    return {path.name.removesuffix(".model.json"): path for path in sorted(folder.glob("*.model.json"))}


def shipped_models() -> dict[str, Path]:
    """{affordance: model file} of the default models inside the package."""
    return models_in(MODELS_DIR)


def choose_models(
    model_files: list[Path], affordances: list[str], layout: FeatureLayout
) -> list[AffordanceModel]:
    """The given model files, else the shipped models of the named affordances, else every shipped model."""
    if model_files:
        models = [load_model(path, layout) for path in model_files]
    else:
        shipped = shipped_models()
        unknown = [name for name in affordances if name not in shipped]
        if unknown:
            raise ModelError(
                f"no shipped model for {', '.join(unknown)}; shipped: {', '.join(shipped) or 'none'} "
                "(or pass --model FILE)"
            )
        models = [load_model(shipped[name], layout) for name in (affordances or list(shipped))]
    wanted = [m for m in models if not affordances or m.affordance in affordances]
    if not wanted:
        raise ModelError(f"none of the models is for {', '.join(affordances)}")
    return wanted
