"""What every learner returns (`learners.LEARNERS`' fit functions), in a module of its own so that a learner
(the cascade) can build one without importing the registry that lists it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np


@dataclass
class Fitted:
    """What a learner returns: the linear (first) stage, its threshold, what the learner reports, and a
    cascade's second stage."""

    weights: np.ndarray
    bias: float
    threshold: float
    report: dict = field(default_factory=dict)
    rescorer: dict | None = None
