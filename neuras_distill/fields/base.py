"""The Field contract (docs/contract.md) as a typing Protocol, its validation, and chunked evaluation.

This module owns:

* :class:`Field`: the structural type every adapter produces and every stage consumes. Nothing subclasses
  it; any object (plain class or ``torch.nn.Module``) with the members below is a field.
* :func:`check_field`: up-front validation raising :class:`~neuras_distill.errors.BadInputError` with a
  message naming what is missing or malformed.
* :func:`evaluate_chunked`: apply a point-wise function to large batches in bounded memory.

Frames: ``x`` are world points (N, 3) in the field's units; ``d`` are unit directions of travel (from the
camera into the scene), world frame, (N, 3).
"""

from __future__ import annotations

import math
from typing import Any, Callable, Protocol, runtime_checkable

import torch

from ..errors import BadInputError

KINDS = ("density", "sdf")


@runtime_checkable
class Field(Protocol):
    """A radiance field with an explicit geometry function.

    Required members:
        kind: ``"density"`` or ``"sdf"``.
        aabb: (2, 3) float tensor ``[min, max]`` in world units holding the foreground geometry.
        geometry(x): x (N, 3) -> (N,) density σ >= 0 per world unit (``density``) or signed distance in
            world units, negative inside (``sdf``).
        radiance(x, d): x (N, 3), d (N, 3) unit directions of travel -> (N, 3) colour in [0, 1].

    Optional members (looked up with ``getattr``; absent means "not provided"):
        background(d): (N, 3) -> (N, 3) colour arriving from infinity.
        background_color: (3,) constant background colour.
        inv_s: float, SDF sharpness (NeuS ``s``), used to turn an SDF into opacity.
        unbounded: bool, content lies outside ``aabb``.
        far_region: a :class:`~neuras_distill.render.far_region.FarRegion` (near and far planes, world units
            along unit rays from the camera): a density field trained with scene contraction holds content out
            to its far plane, which the teacher renders (``teacher.far_steps``) instead of the background.
        cameras: :class:`~neuras_distill.render.cameras.Cameras` the field was trained with.
        surface_level: float, density fields: σ at which the mesh is extracted (default: adaptive level).
        occupancy_grid(resolution): an :class:`~neuras_distill.render.occupancy.OccupancyGrid` over ``aabb``
            containing every cell where the field is non-zero (the renderer skips the rest), or None.
        default_cameras(n, width, height[, held_out_every]): Cameras framing the scene, when none are given.
        lane_shifts: sideways camera shifts (world units) the evaluation extrapolates to (driving scenes).
        preset: name of the ``configs/`` preset that fits the scene (used when no preset or config is given).
        source_digest: str identifying the checkpoint and load options (work-area keys; else the state).
    """

    kind: str
    aabb: torch.Tensor

    def geometry(self, x: torch.Tensor) -> torch.Tensor: ...

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor: ...


def _describe(field: Any) -> str:
    return type(field).__name__


def check_field(field: Any, *, probe: bool = True) -> None:
    """Raise :class:`BadInputError` unless ``field`` satisfies the Field contract.

    Checks ``kind``, ``aabb`` (shape (2, 3), finite, min < max on every axis), that ``geometry`` and
    ``radiance`` are callable, and the optional members when present (``background_color`` (3,) finite,
    ``inv_s`` positive finite, ``background`` callable). With ``probe=True`` the field is also evaluated at
    a few points of its box and the output shapes and finiteness are checked.
    """
    name = _describe(field)
    kind = getattr(field, "kind", None)
    if kind is None:
        raise BadInputError(f"field {name} has no 'kind'; set kind to one of {KINDS}")
    if kind not in KINDS:
        raise BadInputError(f"field {name} has unknown kind {kind!r}; expected one of {KINDS}")

    aabb = getattr(field, "aabb", None)
    if aabb is None:
        raise BadInputError(f"field {name} has no 'aabb'; give a (2, 3) tensor [min, max] holding the geometry")
    try:
        aabb_t = torch.as_tensor(aabb, dtype=torch.float64).detach().cpu()
    except (TypeError, ValueError, RuntimeError):
        raise BadInputError(f"field {name}: aabb is not a tensor of numbers") from None
    if tuple(aabb_t.shape) != (2, 3):
        raise BadInputError(f"field {name}: aabb must have shape (2, 3) [min, max], got {tuple(aabb_t.shape)}")
    if not bool(torch.isfinite(aabb_t).all()):
        raise BadInputError(f"field {name}: aabb contains NaN or Inf: {aabb_t.tolist()}")
    if not bool((aabb_t[0] < aabb_t[1]).all()):
        raise BadInputError(f"field {name}: aabb min must be below max on every axis, got {aabb_t.tolist()}")

    for member in ("geometry", "radiance"):
        if not callable(getattr(field, member, None)):
            raise BadInputError(f"field {name} has no callable '{member}'; see the Field contract in docs/contract.md")

    bg = getattr(field, "background", None)
    if bg is not None and not callable(bg):
        raise BadInputError(f"field {name}: 'background' must be a callable d (N, 3) -> (N, 3)")
    bgc = getattr(field, "background_color", None)
    if bgc is not None:
        try:
            bgc_t = torch.as_tensor(bgc, dtype=torch.float32).reshape(-1)
        except (TypeError, ValueError, RuntimeError):
            raise BadInputError(f"field {name}: background_color is not numeric") from None
        if bgc_t.numel() != 3 or not bool(torch.isfinite(bgc_t).all()):
            raise BadInputError(f"field {name}: background_color must be 3 finite numbers, got {bgc_t.tolist()}")
    inv_s = getattr(field, "inv_s", None)
    if inv_s is not None:
        try:
            inv_s_f = float(inv_s)
        except (TypeError, ValueError, RuntimeError):
            raise BadInputError(f"field {name}: inv_s must be a number, got {inv_s!r}") from None
        if not (math.isfinite(inv_s_f) and inv_s_f > 0):
            raise BadInputError(f"field {name}: inv_s must be positive and finite, got {inv_s_f}")

    if not probe:
        return
    lo, hi = aabb_t[0].float(), aabb_t[1].float()
    frac = torch.tensor([[0.5, 0.5, 0.5], [0.25, 0.7, 0.4], [0.9, 0.1, 0.6], [0.0, 0.0, 0.0]])
    x = lo + frac * (hi - lo)
    d = torch.nn.functional.normalize(torch.tensor([[1.0, 0.2, -0.3]]).expand(4, 3), dim=-1)
    with torch.no_grad():
        try:
            g = field.geometry(x)
            c = field.radiance(x, d)
        except BadInputError:
            raise
        except Exception as exc:  # noqa: BLE001 - a third-party field failing is the user's to fix
            raise BadInputError(f"field {name} failed when evaluated at points of its aabb: "
                                f"{type(exc).__name__}: {exc}") from exc
    if not isinstance(g, torch.Tensor) or tuple(g.shape) not in ((4,), (4, 1)):
        raise BadInputError(f"field {name}: geometry(x) for x (4, 3) must return (4,), "
                            f"got {tuple(getattr(g, 'shape', ())) or type(g).__name__}")
    if not isinstance(c, torch.Tensor) or tuple(c.shape) != (4, 3):
        raise BadInputError(f"field {name}: radiance(x, d) for x (4, 3) must return (4, 3), "
                            f"got {tuple(getattr(c, 'shape', ())) or type(c).__name__}")
    if not bool(torch.isfinite(g).all()) or not bool(torch.isfinite(c).all()):
        raise BadInputError(f"field {name} returns NaN or Inf inside its aabb")
    if kind == "density" and bool((g < 0).any()):
        raise BadInputError(f"field {name}: density must be >= 0, got {g.min().item():.3g}")


def evaluate_chunked(fn: Callable[..., Any], *tensors: torch.Tensor, chunk: int = 2**18) -> Any:
    """``fn(*tensors)`` evaluated on slices of at most ``chunk`` rows (dim 0) and concatenated.

    All ``tensors`` share their first dimension N. ``fn`` returns a tensor or a tuple/list of tensors whose
    first dimension is the slice length; the result has the same structure with first dimension N.
    """
    if not tensors:
        raise ValueError("evaluate_chunked needs at least one tensor")
    n = int(tensors[0].shape[0])
    if any(int(t.shape[0]) != n for t in tensors):
        raise ValueError(f"evaluate_chunked: first dimensions differ: {[tuple(t.shape) for t in tensors]}")
    chunk = max(1, int(chunk))
    if n <= chunk:
        return fn(*tensors)
    outs = [fn(*(t[i:i + chunk] for t in tensors)) for i in range(0, n, chunk)]
    if isinstance(outs[0], (tuple, list)):
        return type(outs[0])(torch.cat([o[k] for o in outs], dim=0) for k in range(len(outs[0])))
    return torch.cat(outs, dim=0)
