"""Wrappers that present one field as another, whatever its format.

This module owns:

* :func:`laplace_density`: VolSDF's Laplace density σ = (1/β)·Ψ_β(−sdf) in the stable ``expm1`` form
  (docs/formats.md §2.4).
* :class:`SDFToDensityField`: wraps any SDF field into a ``"density"`` field with the same radiance, aabb,
  background and cameras (the synthetic scenes' density variants, the NeuS adapter's ``density="laplace"``).
"""

from __future__ import annotations

import math
from typing import Any

import torch

from ..errors import require

DEFAULT_BETA = 0.003


def laplace_density(sdf: torch.Tensor, beta: float) -> torch.Tensor:
    """VolSDF density (N,) from signed distances (N,) (negative inside): σ = (1/β)·Laplace-CDF_β(−sdf).

    Written per side with ``e = exp(−|sdf|/β)``: ``(1 − e/2)/β`` inside, ``(e/2)/β`` outside, so the outside
    tail keeps its relative precision (no ``0.5 − 0.5·(1 − e)`` cancellation) and neither branch overflows.
    σ -> 1/β deep inside, 1/(2β) on the surface, (1/2β)·exp(−sdf/β) outside.
    """
    sdf = sdf.float()
    e = torch.exp(-sdf.abs() / beta)
    return torch.where(sdf > 0, 0.5 * e, 1.0 - 0.5 * e) / beta


class SDFToDensityField:
    """Density view (kind ``"density"``) of an SDF field: σ = :func:`laplace_density` (field.geometry(x), β).

    Radiance, aabb, background, background_color, cameras, unbounded and any other member (e.g.
    ``default_cameras``, ``exact_sdf``) are forwarded to the wrapped field; ``inv_s`` is not (it is an SDF
    notion). ``beta`` is in world units (the width of the surface's density ramp).
    """

    kind = "density"

    def __init__(self, sdf_field: Any, beta: float = DEFAULT_BETA):
        require(getattr(sdf_field, "kind", None) == "sdf",
                f"SDFToDensityField needs a field of kind 'sdf', got {getattr(sdf_field, 'kind', None)!r}")
        require(beta > 0 and math.isfinite(beta), f"beta must be positive and finite, got {beta}")
        self.sdf_field = sdf_field
        self.beta = float(beta)

    @property
    def aabb(self) -> torch.Tensor:
        return self.sdf_field.aabb

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) -> σ (N,) per world unit."""
        return laplace_density(self.sdf_field.geometry(x), self.beta)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        return self.sdf_field.radiance(x, d)

    def __getattr__(self, name: str):
        # only called for members not found normally; forward optional members, never inv_s
        if name in ("sdf_field", "inv_s") or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.sdf_field, name)

    def __repr__(self) -> str:
        return f"SDFToDensityField({self.sdf_field!r}, beta={self.beta})"
