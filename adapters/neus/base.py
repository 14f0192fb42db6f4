"""What the two NeuS-family fields share: :class:`NeuSFamilyField`, the Field contract in the world frame on
top of a network evaluated in its own (unit-sphere) frame.

Both fields (docs/formats.md §2): kind ``"sdf"``; ``aabb`` = the network frame's object box in the world
(NeuS: the cube around the unit sphere; instant-nsr-pl: ``[-radius, radius]^3``); ``geometry(x)`` (N, 3)
world -> (N,) world-unit signed distance, negative inside; ``radiance(x, d)`` (N, 3), unit travel directions
-> (N, 3) in [0, 1] (normals by autograd, enabled locally so callers may run under ``torch.no_grad``);
``inv_s``; ``background_color`` (white unless told); ``cameras`` when a camera file was given. Evaluation is
chunked (``chunk`` points). Outside the network's domain the SDF is bounded: NeuS never trains outside its
unit sphere (its rays are cut there), so :class:`~.mlp_field.NeuSField` intersects its SDF with that sphere
(``bound="sphere"``); the hash grid is undefined outside its box, so
:class:`~.hashgrid_field.HashGridNeuSField` clamps to the box and adds the distance to it.

A subclass builds its networks, calls :meth:`NeuSFamilyField._place` and provides ``sdf_network(p)`` (network
frame, (N, 3) -> (N, 1 + F), SDF first), ``_local_sdf(p)`` (the bounded network-frame SDF),
``_features(out)`` (what its colour network takes from the SDF network's output) and
``_colour(p, grad, d, features)`` (network frame; ``grad`` the unnormalised SDF gradient, ``d`` the direction
of travel rotated into the network frame, its length kept).
"""

from __future__ import annotations

import math

import torch

from neuras_distill.errors import require
from neuras_distill.fields.base import evaluate_chunked

from .frame import SphereFrame
from .layers import shape_of

DEFAULT_CHUNK = None          # None: sized from the network so one chunk's autograd graph stays ~256 MB
ACTIVATION_BUDGET = 2**28     # bytes of activations kept for the normal's backward pass, per chunk
INV_S_RANGE = (1e-6, 1e6)


def inv_s_from_variance(sd: dict, key: str, source: str) -> float:
    """NeuS's sharpness ``s = exp(10 · variance)`` from the scalar ``sd[key]``, clipped to INV_S_RANGE."""
    v = sd.get(key)
    require(isinstance(v, torch.Tensor), f"{source}: missing the variance {key!r} (scalar tensor)")
    require(v.numel() == 1, f"{source}: {key!r} has shape {shape_of(v)}, expected a scalar ()")
    val = float(v.reshape(()).double())
    require(math.isfinite(val), f"{source}: {key!r} is {val}")
    return float(min(max(math.exp(min(10.0 * val, 700.0)), INV_S_RANGE[0]), INV_S_RANGE[1]))


def chunk_size(chunk: int | None, bytes_per_point: int) -> int:
    """Points per evaluation batch: ``chunk`` if given, else what fits ACTIVATION_BUDGET (1024 .. 65536)."""
    if chunk is not None:
        require(int(chunk) >= 1, f"chunk must be >= 1, got {chunk}")
        return int(chunk)
    return int(min(2**16, max(1024, ACTIVATION_BUDGET // max(1, bytes_per_point))))


def background_rgb(background_color) -> torch.Tensor:
    """(3,) float tensor of ``background_color``, white when None (validated: 3 finite numbers)."""
    bg = torch.as_tensor((1.0, 1.0, 1.0) if background_color is None else background_color,
                         dtype=torch.float32).reshape(-1)
    require(bg.numel() == 3 and bool(torch.isfinite(bg).all()),
            f"background_color must be 3 finite numbers, got {bg.tolist()}")
    return bg


class NeuSFamilyField:
    """Base of :class:`~.mlp_field.NeuSField` and :class:`~.hashgrid_field.HashGridNeuSField`: frame,
    sharpness, box, background, cameras, chunking, and the world-frame ``geometry`` / ``radiance`` /
    ``sdf_and_gradient`` built on the subclass's network-frame hooks (see the module docstring)."""

    kind = "sdf"
    #: ``orbit_framing`` padding of :meth:`default_cameras` (None: its default).
    orbit_padding: float | None = None

    def _place(self, *, scale_mat, variance: tuple[dict, str, str], box_half: float, background_color,
               cameras, chunk: int | None, bytes_per_point: int) -> None:
        """Set ``frame``, ``inv_s_network`` (from ``variance`` = (state dict, key, source) as
        :func:`inv_s_from_variance`), ``inv_s`` (world), ``aabb`` (the network cube
        ``[-box_half, box_half]^3`` in the world), ``background_color``, ``cameras`` and ``chunk``."""
        self.frame = SphereFrame(scale_mat)
        self.inv_s_network = inv_s_from_variance(*variance)
        self.inv_s = self.inv_s_network / self.frame.scale
        self.aabb = self.frame.box_to_world(box_half)
        self.background_color = background_rgb(background_color)
        self.cameras = cameras
        self.chunk = chunk_size(chunk, bytes_per_point)

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """An orbit (z up) framing the field's box, for checkpoints that come without cameras."""
        from neuras_distill.scenes.analytic import orbit_framing

        extra = {} if self.orbit_padding is None else {"padding": self.orbit_padding}
        return orbit_framing(self.aabb, n, width, height, **extra)

    # -- hooks (network frame)
    def sdf_network(self, p: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _local_sdf(self, p: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _features(self, out: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _colour(self, p: torch.Tensor, grad: torch.Tensor, d: torch.Tensor,
                features: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def _cast(self, t: torch.Tensor) -> torch.Tensor:
        """Inputs as (N, 3) in the dtype (and device) the networks run in."""
        return t.reshape(-1, 3).float()

    def _sdf_grad(self, p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(SDF (N,), its gradient ∇_p sdf (N, 3), features) at network-frame points (autograd enabled
        locally)."""
        with torch.enable_grad():
            p = p.detach().requires_grad_(True)
            out = self.sdf_network(p)
            (grad,) = torch.autograd.grad(out[:, 0].sum(), p)
        return out[:, 0].detach(), grad.detach(), self._features(out.detach())

    # -- Field contract (world frame)
    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points -> (N,) signed distance in world units, negative inside."""
        return evaluate_chunked(lambda xc: self._local_sdf(self.frame.to_local(xc)) * self.frame.scale,
                                self._cast(x), chunk=self.chunk)

    def sdf_and_gradient(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(network-frame SDF (N,), its gradient ∇_p sdf (N, 3), unnormalised) at world points x (N, 3)."""
        return evaluate_chunked(lambda xc: self._sdf_grad(self.frame.to_local(xc))[:2], self._cast(x),
                                chunk=self.chunk)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points, d (N, 3) unit travel directions -> (N, 3) colour in [0, 1]."""
        def run(xc: torch.Tensor, dc: torch.Tensor) -> torch.Tensor:
            p = self.frame.to_local(xc)
            _, grad, feat = self._sdf_grad(p)
            return self._colour(p, grad, self.frame.dir_to_local(dc), feat)

        return evaluate_chunked(run, self._cast(x), self._cast(d), chunk=self.chunk)
