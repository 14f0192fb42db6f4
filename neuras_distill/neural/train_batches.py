"""The pixels :func:`neuras_distill.neural.train.fit` learns from, and the batches of patches it draws.

Owns: :class:`TrainingPixels` (what ``fit`` is given: the training views' G-buffers and teacher colours, per
view), :class:`PixelRows` (the same checked and flattened to one row per pixel, in host memory),
:class:`SkyPixels` (what the skybox learns from) and :class:`BatchCounts`.

A batch is ``batch_patches`` square patches of side ``p`` centred on random pixels (covered pixels without a
skybox, any pixel with one) of random views, clamped into the image. Pixels are numbered
``view * H * W + y * W + x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from neuras_distill.errors import BadInputError


def _as_tensor(x, dtype, name: str, shape_tail: tuple, lead: tuple | None = None) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x)
    if t.dim() != 3 + len(shape_tail) or tuple(t.shape[3:]) != shape_tail:
        raise BadInputError(f"fit: {name} must have shape (N, H, W{''.join(', ' + str(s) for s in shape_tail)}), "
                            f"got {tuple(t.shape)}")
    if lead is not None and tuple(t.shape[:3]) != lead:
        raise BadInputError(f"fit: {name} has shape {tuple(t.shape)}, expected leading (N, H, W) = {lead}")
    return t.to(dtype)


@dataclass(frozen=True)
class TrainingPixels:
    """The training views as ``fit`` learns from them: ``uv`` (N, H, W, 2) float32 G-buffer texture coordinates,
    ``coverage`` (N, H, W) bool (the mesh covers the pixel), ``dirs`` (N, H, W, C) float32 view inputs
    (C = ``model.view_columns``: ``neural.model.view_inputs``), ``targets`` (N, H, W, 3) float32 teacher colours;
    for a skybox trained with them, ``origins`` (N, 3) float32 camera centres relative to the skybox's centre and
    the optional ``sky_pixels`` (N, H, W) bool, the uncovered pixels it learns from (default: all of them; an
    uncovered pixel outside it is left out of the loss). numpy arrays or tensors, in host memory."""

    uv: object
    coverage: object
    dirs: object
    targets: object
    origins: object = None
    sky_pixels: object = None

    def rows(self, view_columns: int, with_sky: bool = False) -> "PixelRows":
        """:meth:`PixelRows.of` these views."""
        return PixelRows.of(self.uv, self.coverage, self.dirs, self.targets, view_columns, with_sky, self.origins,
                            self.sky_pixels)


@dataclass
class SkyPixels:
    """What the skybox learns from: ``origins`` (N, 3) float32 camera centres relative to the skybox's centre
    (on the training device once :meth:`PixelRows.to` ran) and ``allowed`` (N*H*W,) bool, the pixels the
    mesh does not cover that the skybox may learn (the others are left out of the loss)."""

    origins: torch.Tensor
    allowed: torch.Tensor


@dataclass
class BatchCounts:
    """Pixels of a whole batch: covered by the mesh, learnt by the skybox, and learnt at all."""

    mesh: int
    sky: int
    learned: int

    @staticmethod
    def of(covered: torch.Tensor, sky_allowed: torch.Tensor | None) -> BatchCounts:
        """covered, sky_allowed: (P,) bool over the batch's pixels (sky_allowed None: no skybox)."""
        mesh = int(covered.sum())
        sky = 0 if sky_allowed is None else int((~covered & sky_allowed).sum())
        return BatchCounts(mesh, sky, mesh + sky)


@dataclass
class PixelRows:
    """The training views, one row per pixel: ``uv`` (P, 2) float32 atlas coordinates, ``dirs`` (P, C) float32
    view inputs, ``targets`` (P, 3) float32 teacher colours, ``covered`` (P,) bool (the mesh covers the pixel),
    with P = N*H*W; ``centres`` (K,) int64, the pixels a patch may be centred on; ``sky`` the skybox's pixels
    (None without a skybox); ``lead`` = (N, H, W)."""

    uv: torch.Tensor
    dirs: torch.Tensor
    targets: torch.Tensor
    covered: torch.Tensor
    centres: torch.Tensor
    sky: SkyPixels | None
    lead: tuple[int, int, int]

    @classmethod
    def of(cls, uv, coverage, dirs, targets, view_columns: int, with_sky: bool = False, origins=None,
           sky_pixels=None) -> PixelRows:
        """Check and flatten ``fit``'s arrays: uv (N, H, W, 2), coverage (N, H, W) bool, dirs (N, H, W,
        ``view_columns``), targets (N, H, W, 3); with a skybox (``with_sky``) also origins (N, 3) and the optional
        sky_pixels (N, H, W) bool (default: every uncovered pixel). Raises BadInputError naming the bad one."""
        cov = _as_tensor(coverage, torch.bool, "coverage", ())
        lead = tuple(cov.shape)
        uv_t = _as_tensor(uv, torch.float32, "uv", (2,), lead)
        dirs_t = _as_tensor(dirs, torch.float32, "dirs", (view_columns,), lead)
        tgt_t = _as_tensor(targets, torch.float32, "targets", (3,), lead)
        cov_f = cov.reshape(-1)
        centres = torch.nonzero(cov_f).flatten()
        if centres.numel() == 0:
            raise BadInputError("fit: no pixel is covered by the mesh in any training view")
        sky = None
        if with_sky:
            if origins is None:
                raise BadInputError("fit: a skybox needs the camera centres (origins) of the training views")
            origins_t = torch.as_tensor(np.asarray(origins, dtype=np.float32)).reshape(-1, 3)
            if origins_t.shape[0] != lead[0]:
                raise BadInputError(f"fit: origins has {origins_t.shape[0]} rows for {lead[0]} views")
            centres = torch.arange(cov_f.numel())            # patches anywhere: the sky is trained too
            allowed = (torch.ones(cov_f.numel(), dtype=torch.bool) if sky_pixels is None
                       else _as_tensor(sky_pixels, torch.bool, "sky_pixels", (), lead).reshape(-1))
            sky = SkyPixels(origins_t, allowed)
        return cls(uv_t.reshape(-1, 2), dirs_t.reshape(-1, dirs_t.shape[-1]), tgt_t.reshape(-1, 3), cov_f,
                   centres, sky, lead)

    def patch_side(self, patch: int) -> int:
        """The patch side used: ``patch``, clipped to the views' height and width (at least 1)."""
        return int(max(1, min(patch, self.lead[1], self.lead[2])))

    def draw(self, gen: torch.Generator, batch_patches: int, p: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(pix (batch_patches, p, p) int64 pixel numbers, view (batch_patches,) int64) of one batch of patches,
        drawn with ``gen``."""
        _, h, w = self.lead
        dy, dx = torch.meshgrid(torch.arange(p), torch.arange(p), indexing="ij")
        c = self.centres[torch.randint(0, self.centres.numel(), (batch_patches,), generator=gen)]
        view = torch.div(c, h * w, rounding_mode="floor")
        rem = c - view * (h * w)
        cy = torch.div(rem, w, rounding_mode="floor")
        cx = rem - cy * w
        top = (cy - p // 2).clamp(0, h - p)
        left = (cx - p // 2).clamp(0, w - p)
        return view[:, None, None] * (h * w) + (top[:, None, None] + dy) * w + (left[:, None, None] + dx), view

    def counts(self, pix: torch.Tensor) -> BatchCounts:
        """The :class:`BatchCounts` of the pixels ``pix`` (any shape, int64)."""
        flat = pix.reshape(-1)
        return BatchCounts.of(self.covered[flat], None if self.sky is None else self.sky.allowed[flat])
