"""Intervals of an SDF march that may hide a surface between their endpoints, and their refinement.

The NeuS opacity of an interval (:func:`~.compositing.alpha_from_sdf`) takes the SDF as linear between the two
endpoints. A part thinner than the step (a pole, a wire, a car's roof edge seen at grazing angles) can lie
between two samples that both see empty space: rays whose samples land inside it see it, their neighbours'
do not, and the part renders as a striped translucent smear. A signed distance changes by at most the distance
moved, so inside an interval of length ``dt`` whose endpoints are ``f_a``, ``f_b`` the SDF can reach as low
as ``(f_a + f_b - dt) / 2``. Where that bound is low enough to hold opacity and below what the linear
interpolation sees, :func:`refine_thin_intervals` evaluates the SDF at ``pieces - 1`` points inside the
interval (:func:`substeps`: enough that each piece is about half the opacity ramp) and composites the
sub-intervals into the interval's opacity and the place its colour is taken.

Owns :func:`thin_intervals` (which intervals), :func:`substeps` (into how many pieces) and
:func:`refine_thin_intervals` (their opacity and colour position). Rays are in the field's frame with unit
directions; distances along them.
"""

from __future__ import annotations

import math

import torch

from .compositing import alpha_from_sdf, sdf_weight_centre, weights_from_alpha

#: An interval is refined when the SDF could dip to where the NeuS opacity reaches e^-5 of its full value
#: (``inv_s * dip < DIP_OPACITY_SCALE``) and at least ``DIP_MARGIN / inv_s`` below both of its endpoints.
DIP_OPACITY_SCALE = 5.0
DIP_MARGIN = 0.5
#: A refined interval is split into sub-intervals at most this many NeuS scales long (``SUB_STEP_SCALE /
#: inv_s``: the opacity ramp is about 6 of them), and into 2 to ``MAX_SUBSTEPS`` of them.
SUB_STEP_SCALE = 3.0
MAX_SUBSTEPS = 16


def substeps(step: float, inv_s: float) -> int:
    """Sub-intervals per refined interval of a march with steps of length ``step`` and NeuS sharpness ``inv_s``."""
    return int(min(MAX_SUBSTEPS, max(2, math.ceil(inv_s * step / SUB_STEP_SCALE))))


def thin_intervals(f: torch.Tensor, dt: torch.Tensor, inv_s: float, occupied: torch.Tensor) -> torch.Tensor:
    """(A, K) bool: the ``occupied`` intervals with an endpoint outside (an SDF in ``f`` (A, K + 1) positive)
    inside which a 1-Lipschitz SDF could dip (over their length ``dt`` (A,)) below both endpoints, to where it
    holds opacity: a part between two samples that both see empty space, or one whose near face the first
    sample has just passed. Intervals inside a solid (both ends negative) are left as they are: a ray there
    has already lost its transmittance."""
    fa, fb = f[:, :-1], f[:, 1:]
    dip = 0.5 * (fa + fb - dt[:, None])
    return (occupied & (torch.maximum(fa, fb) > 0) & (inv_s * dip < DIP_OPACITY_SCALE)
            & (inv_s * (torch.minimum(fa, fb) - dip) > DIP_MARGIN))


def refine_thin_intervals(geometry, o: torch.Tensor, d: torch.Tensor, t_start: torch.Tensor, dt: torch.Tensor,
                          fa: torch.Tensor, fb: torch.Tensor, inv_s: float,
                          pieces: int) -> tuple[torch.Tensor, torch.Tensor, int]:
    """The opacity of M intervals, each split into ``pieces`` equal sub-intervals (:func:`substeps`).

    ``geometry``: the field's (N, 3) -> (N,) SDF; ``o``, ``d`` (M, 3) ray origins and unit directions;
    ``t_start``, ``dt`` (M,) where each interval starts and its length; ``fa``, ``fb`` (M,) its endpoint SDFs.
    Returns (alpha (M,): one minus the product of the sub-intervals' transmittances, colour position (M,): the
    mean of the interval's weight as a fraction of its length, 0.5 where it holds none, and the number of SDF
    evaluations made)."""
    m = fa.shape[0]
    frac = torch.arange(1, pieces, dtype=torch.float32, device=o.device) / pieces            # (R - 1,)
    t_in = t_start[:, None] + frac[None, :] * dt[:, None]                                         # (M, R - 1)
    pts = o[:, None, :] + t_in[..., None] * d[:, None, :]
    inner = geometry(pts.reshape(-1, 3)).reshape(m, pieces - 1).float()
    g = torch.cat([fa[:, None].float(), inner, fb[:, None].float()], dim=1)                       # (M, R + 1)
    sub_alpha = alpha_from_sdf(g[:, :-1], g[:, 1:], inv_s)                                        # (M, R)
    w, _ = weights_from_alpha(sub_alpha)
    alpha = w.sum(-1).clamp(0.0, 1.0)
    sub_centre = sdf_weight_centre(g[:, :-1], g[:, 1:], inv_s)
    index = torch.arange(pieces, dtype=torch.float32, device=o.device)
    position = ((index[None, :] + sub_centre) * w).sum(-1) / pieces / alpha.clamp(min=1e-12)
    position = torch.where(alpha > 0, position.clamp(0.0, 1.0), torch.full_like(position, 0.5))
    return alpha, position, pts.shape[0] * (pieces - 1)


__all__ = ["thin_intervals", "substeps", "refine_thin_intervals"]
