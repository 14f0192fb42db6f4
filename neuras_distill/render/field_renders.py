"""The field's renders of a camera set, as the teacher, the evaluation and the worker processes return them."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class FieldRenders:
    """The field's renders of a camera set: ``images`` (H, W, 3), ``opacities`` (H, W), ``surface_depths`` and
    ``fringe_depths`` (H, W) (distance along the unit ray where the opacity reaches 0.5 and
    ``render.volume.FRINGE_OPACITY``, 0 where it never does) per view, and ``seconds`` per frame."""

    images: list[np.ndarray]
    opacities: list[np.ndarray]
    surface_depths: list[np.ndarray]
    fringe_depths: list[np.ndarray]
    seconds: list[float]
