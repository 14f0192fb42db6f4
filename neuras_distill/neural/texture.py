"""The learnable UV feature map and the bilinear-corner convention shared with the GLSL shader.

Owns: :class:`NeuralTexture` (a (H, W, D) parameter, row j = v index, column i = u index) and
:func:`bilinear_corners`, the hand-done bilinear lookup of ``docs/architecture.md``::

    x = u*W - 0.5, y = v*H - 0.5, i0 = floor(x), j0 = floor(y), fx = x - i0, fy = y - j0
    corners (i0,j0), (i0+1,j0), (i0,j0+1), (i0+1,j0+1), clamped to [0, W-1] x [0, H-1]
    weights (1-fx)(1-fy), fx(1-fy), (1-fx)fy, fx fy

``bake/glsl.py`` emits exactly the same arithmetic (same order of operations, float32).

Atlas pages (``pages`` P > 1, docs/architecture.md "Atlas pages"): the atlas is P square pages of side S stacked
along v (H = P * S); a uv's page is ``p = min(floor(v * P), P - 1)`` and its row within the page
``y = (v * P - p) * S - 0.5``, the corner rows clamped to the page's own rows, as a texture array's layer is
addressed in GLSL (each page its own layer, CLAMP_TO_EDGE within it).
"""

from __future__ import annotations

import math
import warnings

import torch
from torch import nn

# torch 2.11 (seen with 2.11.0+cu130 on an H100) warns once per process that sparse invariant checks are off
# when the atlas's sparse gradient is built with ``check_invariants=False`` on purpose (the indices are made
# in range here); the warning told the user nothing they could act on.
warnings.filterwarnings("ignore", message="Sparse invariant checks are implicitly disabled")


def bilinear_corners(uv: torch.Tensor, height: int, width: int, pages: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
    """Corner texels and weights of a bilinear lookup.

    Args:
        uv: (B, 2) float texture coordinates (u right, v up; [0, 1] covers the texture).
        height, width: texture size H (rows, v) and W (columns, u).
        pages: P square pages stacked along v (H = P * W); the corners are clamped within the uv's page.

    Returns:
        idx: (B, 4) int64 flat texel indices ``j * W + i`` of the corners (i0,j0), (i0+1,j0), (i0,j0+1),
            (i0+1,j0+1), each clamped to the texture.
        weights: (B, 4) float32 weights (1-fx)(1-fy), fx(1-fy), (1-fx)fy, fx fy; they sum to 1.
    """
    uv = uv.to(torch.float32)
    x = uv[:, 0] * float(width) - 0.5
    rows, first_row = height, 0
    if pages > 1:
        rows = height // pages
        vp = uv[:, 1] * float(pages)
        page = torch.clamp(torch.floor(vp), 0.0, float(pages - 1))
        y = (vp - page) * float(rows) - 0.5
        first_row = page.long() * rows
    else:
        y = uv[:, 1] * float(height) - 0.5
    x0 = torch.floor(x)
    y0 = torch.floor(y)
    fx = x - x0
    fy = y - y0
    i0 = x0.long()
    j0 = y0.long()
    i1 = (i0 + 1).clamp_(0, width - 1)
    j1 = (j0 + 1).clamp_(0, rows - 1) + first_row
    i0 = i0.clamp_(0, width - 1)
    j0 = j0.clamp_(0, rows - 1) + first_row
    idx = torch.stack([j0 * width + i0, j0 * width + i1, j1 * width + i0, j1 * width + i1], dim=1)
    gx = 1.0 - fx
    gy = 1.0 - fy
    weights = torch.stack([gx * gy, fx * gy, gx * fy, fx * fy], dim=1)
    return idx, weights


#: Texels whose coarse lookups :meth:`NeuralTexture.features_flat` computes at once.
_FOLD_CHUNK = 1 << 20


class NeuralTexture(nn.Module):
    """A learnable feature atlas, optionally with a coarse level under it.

    A texel's feature is ``data[j, i]`` plus, with ``coarse_factor`` f > 1, the bilinear lookup of a coarse atlas
    (f times fewer texels a side, same pages) at the texel's centre. The coarse level only reparametrises the
    atlas: what is baked is the sum at every texel (:meth:`fold_coarse`), so the bundle's format does not change.
    Each coarse texel gathers the gradients of about f x f fine texels, so a flat surface whose fine texels see
    few training samples each still converges.

    Attributes:
        data: (H, W, D) float32 parameter; ``data[j, i]`` is texel (i, j), centred at uv ((i+0.5)/W, (j+0.5)/H).
        coarse: (H / f, W / f, D) float32 parameter (zeros at start), or None without a coarse level.
    """

    def __init__(self, height: int, width: int, dim: int, init_std: float = 1e-2,
                 generator: torch.Generator | None = None, coarse_factor: int = 1, pages: int = 1) -> None:
        super().__init__()
        if height < 1 or width < 1 or dim < 1:
            raise ValueError(f"NeuralTexture needs positive sizes, got {height}x{width}x{dim}")
        self.height, self.width, self.dim = int(height), int(width), int(dim)
        self.pages = int(pages)
        self.data = nn.Parameter(torch.randn(self.height, self.width, self.dim, generator=generator) * init_std)
        self.coarse_factor = max(1, int(coarse_factor))
        self.coarse = None
        if self.coarse_factor > 1:
            self.coarse_width = max(1, self.width // self.coarse_factor)
            self.coarse_height = (self.pages * self.coarse_width if self.pages > 1
                                  else max(1, self.height // self.coarse_factor))
            self.coarse = nn.Parameter(torch.zeros(self.coarse_height, self.coarse_width, self.dim))

    @property
    def flat(self) -> torch.Tensor:
        """(H*W, D) view of the fine texels, row-major (index j*W + i); without the coarse level."""
        return self.data.view(self.height * self.width, self.dim)

    def _coarse_at(self, flat_idx: torch.Tensor) -> torch.Tensor:
        """The coarse level's bilinear lookup at the centres of fine texels ``flat_idx`` (N,) -> (N, D)."""
        j = torch.div(flat_idx, self.width, rounding_mode="floor")
        i = flat_idx - j * self.width
        uv = torch.stack([(i.float() + 0.5) / self.width, (j.float() + 0.5) / self.height], dim=1)
        idx, w = bilinear_corners(uv, self.coarse_height, self.coarse_width, self.pages)
        corners = _DenseGather.apply(self.coarse, idx.reshape(-1)).view(*idx.shape, self.dim)
        w = w.to(corners.dtype)
        return (w[:, 0:1] * corners[:, 0] + w[:, 1:2] * corners[:, 1]
                + w[:, 2:3] * corners[:, 2] + w[:, 3:4] * corners[:, 3])

    def gather(self, flat_idx: torch.Tensor, sparse_grad: bool = True) -> torch.Tensor:
        """Texel features (fine + coarse) at flat indices (any shape, values j*W + i) -> (*idx.shape, D).

        Each distinct texel is read once and its row shared by every lookup of it, so with ``sparse_grad`` the
        gradient of ``data`` is a sparse COO tensor (sparse dims (j, i), dense D) holding each touched texel once,
        for ``torch.optim.SparseAdam`` (lazy Adam: a step costs O(batch), not O(H*W*D)). One row per lookup
        instead (four per sample, most texels shared by neighbouring pixels) left SparseAdam a sort and merge
        that took 14% of a step on a 2048² atlas.
        ``coarse`` (f² times smaller) always gets a dense gradient: coalescing a sparse one cost more than the
        dense Adam step.
        """
        uniq, inv = torch.unique(flat_idx.reshape(-1), return_inverse=True)
        if sparse_grad and torch.is_grad_enabled() and self.data.requires_grad:
            own = _SparseGather.apply(self.data, uniq)
        else:
            own = self.flat[uniq]
        if self.coarse is not None:
            own = own + self._coarse_at(uniq)
        return torch.index_select(own, 0, inv).view(*flat_idx.shape, self.dim)

    @torch.no_grad()
    def features_flat(self) -> torch.Tensor:
        """(H*W, D) every texel's feature, fine + coarse (detached): what the atlas bakes to."""
        flat = self.flat.detach()
        if self.coarse is None or not bool(self.coarse.any()):     # none, or folded in (a trained model's)
            return flat
        out = flat.clone()
        for start in range(0, flat.shape[0], _FOLD_CHUNK):        # a 4096² atlas at once would take gigabytes
            rows = torch.arange(start, min(start + _FOLD_CHUNK, flat.shape[0]), device=flat.device)
            out[rows] += self._coarse_at(rows)
        return out

    @torch.no_grad()
    def fold_coarse(self) -> None:
        """Add the coarse level into the fine texels and zero it: every feature stays the same, all in ``data``."""
        if self.coarse is not None:
            self.flat.copy_(self.features_flat())
            self.coarse.zero_()

    def extra_repr(self) -> str:
        return f"height={self.height}, width={self.width}, dim={self.dim}"


class _SparseGather(torch.autograd.Function):
    """rows = param.view(-1, D)[idx] with a sparse COO gradient for param (H, W, D). Given ``torch.unique``'s
    sorted distinct indices, the gradient holds each texel once, in order, and is marked coalesced."""

    @staticmethod
    def forward(ctx, param: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        ctx.save_for_backward(idx)
        ctx.shape = tuple(param.shape)
        return param.reshape(-1, param.shape[-1])[idx]

    @staticmethod
    def backward(ctx, grad: torch.Tensor):  # type: ignore[override]
        (idx,) = ctx.saved_tensors
        h, w, d = ctx.shape
        ind = torch.stack([torch.div(idx, w, rounding_mode="floor"), idx % w])
        return torch.sparse_coo_tensor(ind, grad.contiguous(), (h, w, d), check_invariants=False,
                                       is_coalesced=True), None


class _DenseGather(_SparseGather):
    """rows = param.view(-1, D)[idx] (the same forward) with a dense gradient for param (..., D), the rows'
    gradients summed into it with ``index_add_``."""

    @staticmethod
    def backward(ctx, grad: torch.Tensor):  # type: ignore[override]
        (idx,) = ctx.saved_tensors
        d = ctx.shape[-1]
        out = torch.zeros(math.prod(ctx.shape) // d, d, dtype=grad.dtype, device=grad.device)
        return out.index_add_(0, idx, grad).view(ctx.shape), None
