"""The volume renderer of a field: the distillation teacher and the "before" side of the speed comparison.

This module owns :class:`VolumeRenderer`. It is a fair, good renderer (docs/decisions.md "A fair before"):

* rays are clipped to the field's aabb with a robust slab test (:func:`~neuras_distill.render.rays.ray_aabb`);
* uniform marching with ``num_steps`` steps across the aabb diagonal (step = diagonal / num_steps; each
  ray's interval [t_near, t_far] is split into ceil(length / step) equal steps);
* empty-space skipping with an :class:`~neuras_distill.render.occupancy.OccupancyGrid`: candidate samples are
  generated for a segment of ``segment`` steps of every live ray at once, tested against the grid, and
  only occupied samples are compacted and sent to the field;
* early termination: after each segment, rays whose transmittance fell below ``early_stop`` are dropped;
* radiance is evaluated only at samples whose compositing weight exceeds ``min_weight``;
* a ray's compositing does not depend on the other rays of its chunk (how many are live sets the round
  length; rounds are composited in blocks of ``segment`` steps, the optical depth summed in float64): on the
  CPU, with a field that evaluates each point on its own, a ray renders bit for bit as it does alone;
* everything else is float32, chunked over rays (memory bounded at any resolution), under ``torch.no_grad``;
* it computes on the field's device (``device=`` overrides): rays, occupancy grid and compositing move there,
  :meth:`render` returns host numpy, :meth:`time_frames` synchronises the device around each timed frame and
  leaves a warm-up frame untimed on a GPU.

Unbounded fields (a ``far_region``, :class:`~neuras_distill.render.far_region.FarRegion`, on a density field,
with ``far_steps`` > 0) are rendered as their trainer renders them: each ray also marches the space between its
near plane and the box (in front) and between the box and its far plane (behind), with ``far_steps`` samples
spaced as :mod:`~neuras_distill.render.far_region` says; the outputs' ``opacity`` and depths stay the
foreground box's (as seen through what lies in front of it), ``rgb`` is the whole picture.

Opacity models: density fields use σ at the interval midpoints with α = 1 − exp(−σδ) and the colour at the
midpoint, as their trainers sample them (stable forms in :mod:`~neuras_distill.render.compositing`); SDF
fields use the NeuS discrete opacity from the SDF at the interval endpoints (``field.inv_s``, or
1000 / (aabb diagonal / √3) if absent) and the colour where the interval's opacity lies, at the mean of its
weight with the SDF linear along it (:func:`~neuras_distill.render.compositing.sdf_weight_centre`): a
surface sharper than the step is crossed anywhere in its interval, and colour sampled at the midpoint drew
the step pattern into every colour that varies across the surface. The background (``field.background(d)``,
else ``field.background_color``, else black) is composited behind: ``rgb = Σ w c + (1 − Σ w) · bg``.

Outputs per pixel: ``rgb`` in [0, 1]; ``opacity`` = Σ w; ``depth`` = Σ w t / Σ w, the expected distance
along the (unit) ray from the camera centre, not the camera-space z (0 where opacity is 0);
``surface_depth`` = the distance at which the accumulated opacity reaches 0.5 (linear within the step; 0 where
it never does): the visible surface, where the expected depth of a soft fringe lies deeper; ``fringe_depth``
the same at opacity :data:`FRINGE_OPACITY` (where a soft fringe starts).
"""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from ..config import TeacherConfig
from ..device import chunk_for_memory, field_device, synchronize
from ..errors import require
from .compositing import alpha_from_sdf, exclusive_cumsum, optical_depth, sdf_weight_centre
from .far_region import FarRegion, march_interval
from .local_frame import LocalFrameField, box_centre, far_from_origin
from .occupancy import OccupancyGrid, default_inv_s
from .rays import ray_aabb

#: Opacity at which a soft fringe starts (``fringe_depth``; the silhouette band of the metrics starts at 0.02,
#: the fringe width and the shell's coverage check at 0.05).
FRINGE_OPACITY = 0.05
OUTPUTS = ("rgb", "depth", "surface_depth", "fringe_depth", "opacity")

#: The library's defaults are the configuration's (one place: ``config.py``).
_TEACHER = TeacherConfig()
_FAR_SDF = 1e3  # SDF value used for endpoints that were not evaluated (masked out anyway)


class VolumeRenderer:
    """Volume-render a field (kind ``"density"`` or ``"sdf"``) for cameras or raw rays.

    Args:
        field: any object satisfying the Field contract.
        num_steps: uniform steps across the aabb diagonal (step length = diagonal / num_steps).
        chunk: rays processed together (bounds memory: about chunk * segment * 40 bytes of temporaries).
        occupancy: ``None`` (no skipping), an :class:`OccupancyGrid`, or ``"auto"``: the field's own
            ``occupancy_grid(resolution)`` when it has one (it must contain every cell where the field is
            non-zero), else built from the field at ``occupancy_resolution``.
        early_stop: a ray stops once its transmittance is below this.
        segment: steps generated per ray per round (between early-termination checks).
        min_weight: samples with a smaller compositing weight get no radiance evaluation.
        far_steps: samples per ray between the near and far planes of an unbounded density field's
            ``far_region`` (0: the box only, the far region's colour left to the background).
    """

    def __init__(self, field, num_steps: int = _TEACHER.num_steps, chunk: int = 2**15, occupancy="auto",
                 early_stop: float = 1e-4, *, segment: int = 32, min_weight: float = 1e-5,
                 occupancy_resolution: int = _TEACHER.occupancy_resolution, device: torch.device | str | None = None,
                 far_steps: int = _TEACHER.far_steps):
        require(getattr(field, "kind", None) in ("density", "sdf"),
                f"cannot volume-render a field of kind {getattr(field, 'kind', None)!r}")
        require(int(num_steps) >= 1, f"num_steps must be >= 1, got {num_steps}")
        self.device = torch.device(device) if device is not None else field_device(field)
        # a box far from the world origin is marched in a frame around its centre (``local_frame``): float32
        # sample positions there are as fine as around the origin, and the field gets them back in float64
        self.frame = LocalFrameField(field, box_centre(field.aabb)) if far_from_origin(field.aabb) else None
        self.world_field = field                        # as given: what another process rebuilds this renderer on
        field = self.frame if self.frame is not None else field
        self.field = field
        self.kind = field.kind
        self.aabb = torch.as_tensor(field.aabb, dtype=torch.float32).reshape(2, 3).to(self.device)
        self.num_steps = int(num_steps)
        self.diagonal = float((self.aabb[1] - self.aabb[0]).norm().cpu())
        self.step = self.diagonal / self.num_steps
        self.segment = max(1, int(segment))
        # on a GPU: as many rays as a quarter of its free memory holds (about segment * 40 bytes each, x4 for
        # the field's own temporaries); on the CPU the given chunk
        self.chunk = max(1, chunk_for_memory(int(chunk), self.segment * 160, self.device))
        self.early_stop = float(early_stop)
        # a ray stops once the optical depth in front of it reaches this (transmittance <= early_stop)
        self._stop_tau = -math.log(self.early_stop) if self.early_stop > 0 else math.inf
        self.min_weight = float(min_weight)
        self.inv_s = default_inv_s(field) if self.kind == "sdf" else None
        if isinstance(occupancy, str):
            require(occupancy == "auto", f"occupancy must be None, an OccupancyGrid or 'auto', got {occupancy!r}")
            provided = getattr(field, "occupancy_grid", None)  # a field's own grid (e.g. instant-ngp's)
            occupancy = provided(occupancy_resolution) if callable(provided) else None
            if occupancy is None:
                occupancy = OccupancyGrid.from_field(field, occupancy_resolution, step=self.step)
        if occupancy is not None and self.frame is not None and far_from_origin(occupancy.aabb):
            occupancy = OccupancyGrid(self.frame.local(occupancy.aabb.cpu()), occupancy.occupied)  # a world grid
        self.occupancy: OccupancyGrid | None = occupancy.to(self.device) if occupancy is not None else None
        self.stats = {"geometry_points": 0, "radiance_points": 0, "rays": 0, "far_points": 0}
        require(int(far_steps) >= 0, f"far_steps must be >= 0, got {far_steps}")
        self.far_steps = int(far_steps)
        region = getattr(field, "far_region", None)
        self.far_region: FarRegion | None = (region if self.far_steps and self.kind == "density"
                                             and isinstance(region, FarRegion) else None)
        self.far_step = self.far_region.step(self.far_steps) if self.far_region is not None else 0.0

    def __repr__(self) -> str:
        far = f", far_region={self.far_region}, far_steps={self.far_steps}" if self.far_region is not None else ""
        return (f"VolumeRenderer(kind={self.kind}, num_steps={self.num_steps}, step={self.step:.4g}, "
                f"occupancy={self.occupancy!r}, early_stop={self.early_stop}{far})")

    # ------------------------------------------------------------------ background
    def background(self, dirs: torch.Tensor) -> torch.Tensor:
        """(N, 3) background colour for unit directions (N, 3)."""
        bg_fn = getattr(self.field, "background", None)
        if callable(bg_fn):
            return bg_fn(dirs).float().reshape(-1, 3)
        color = getattr(self.field, "background_color", None)
        if color is None:
            return torch.zeros_like(dirs)
        return torch.as_tensor(color, dtype=torch.float32).to(dirs.device).reshape(1, 3).expand_as(dirs)

    # ------------------------------------------------------------------ rays
    @torch.no_grad()
    def render_rays(self, origins: torch.Tensor, dirs: torch.Tensor, *,
                    crossings: bool = False) -> dict[str, torch.Tensor]:
        """Render rays: origins (N, 3), unit directions of travel (N, 3), world frame.

        Returns ``{"rgb": (N, 3), "depth", "surface_depth", "fringe_depth", "opacity": (N,)}`` float32 tensors;
        the surface and fringe depths only with ``crossings`` (zeros otherwise; the teacher asks for them).
        """
        origins = origins.reshape(-1, 3)
        origins = (self.frame.local(origins) if self.frame is not None else origins.float()).to(self.device)
        dirs = dirs.reshape(-1, 3).float().to(self.device)
        outs = [self._render_chunk(origins[i:i + self.chunk], dirs[i:i + self.chunk], crossings)
                for i in range(0, origins.shape[0], self.chunk)]
        return {k: torch.cat([o[k] for o in outs], dim=0) for k in OUTPUTS}

    def _render_chunk(self, origins: torch.Tensor, dirs: torch.Tensor,
                      crossings: bool = False) -> dict[str, torch.Tensor]:
        n_rays = origins.shape[0]
        self.stats["rays"] += n_rays
        on = {"device": origins.device}
        out_rgb = torch.zeros(n_rays, 3, **on)
        out_wt = torch.zeros(n_rays, **on)
        out_w = torch.zeros(n_rays, **on)
        out_half = torch.zeros(n_rays, 2, **on)
        region = self.far_region
        t_near, t_far, hit = ray_aabb(origins, dirs, self.aabb, near=region.near if region is not None else 0.0)
        if region is not None:      # in front of the box (the whole ray where it misses the box)
            near = torch.full_like(t_near, region.near)
            front_rgb = torch.zeros(n_rays, 3, **on)
            front_end = torch.where(hit, t_near, torch.full_like(t_near, region.far)).clamp(max=region.far)
            trans0 = self._far_march(origins, dirs, near, front_end, torch.ones(n_rays, **on), front_rgb)
        ids = torch.nonzero(hit).flatten()
        if ids.numel():
            # state of the live rays, compacted whenever some of them finish
            o, d, t0 = origins[ids], dirs[ids], t_near[ids]
            length = t_far[ids] - t0
            n_steps = torch.ceil(length / self.step).clamp(min=1)
            dt = length / n_steps
            acc_rgb = torch.zeros(ids.numel(), 3, **on)
            acc_wt = torch.zeros(ids.numel(), dtype=torch.float64, **on)      # float64 running sums: see
            acc_w = torch.zeros(ids.numel(), dtype=torch.float64, **on)       # _march_segment
            acc_half = torch.zeros(ids.numel(), 2, **on)
            # optical depth in front of the live rays (transmittance exp(-tau_in)), float64
            tau_in = (-torch.log(trans0[ids].double()) if region is not None
                     else torch.zeros(ids.numel(), dtype=torch.float64, **on))
            longest, started = int(n_steps.max()), ids.numel()
            k0 = 0
            while ids.numel():
                ks = torch.arange(self._steps_this_round(started, ids.numel(), longest - k0), dtype=torch.float32,
                                  **on)
                tau_in = self._march_segment(k0, ks, o, d, t0, dt, n_steps, tau_in, acc_rgb, acc_wt, acc_w,
                                            acc_half if crossings else None)
                k0 += ks.numel()
                keep = (tau_in < self._stop_tau) & (n_steps > k0)
                if bool(keep.all()):
                    continue
                done = ~keep
                out_rgb[ids[done]] = acc_rgb[done]
                out_wt[ids[done]] = acc_wt[done].float()
                out_w[ids[done]] = acc_w[done].float()
                out_half[ids[done]] = acc_half[done]
                ids, o, d, t0, dt, n_steps, tau_in, acc_rgb, acc_wt, acc_w, acc_half = (
                    v[keep] for v in (ids, o, d, t0, dt, n_steps, tau_in, acc_rgb, acc_wt, acc_w, acc_half))
        depth = torch.where(out_w > 0, out_wt / out_w.clamp(min=1e-12), torch.zeros_like(out_w))
        if region is not None:      # behind the box, then the background behind what is left
            behind = (trans0 - out_w).clamp(min=0.0)
            start = torch.maximum(t_far, near)
            behind = self._far_march(origins, dirs, torch.where(hit, start, near), torch.where(
                hit, torch.full_like(t_far, region.far), near), behind, front_rgb)
            rgb = out_rgb + front_rgb + behind[:, None] * self.background(dirs)
        else:
            rgb = out_rgb + (1.0 - out_w).clamp(min=0.0)[:, None] * self.background(dirs)
        return {"rgb": rgb.clamp(0.0, 1.0), "depth": depth, "surface_depth": out_half[:, 0],
                "fringe_depth": out_half[:, 1], "opacity": out_w.clamp(0.0, 1.0)}

    def _far_march(self, o, d, t_a, t_b, trans, acc_rgb) -> torch.Tensor:
        """:func:`~.far_region.march_interval` over [t_a, t_b] of each ray (N,) with this renderer's settings."""
        return march_interval(self.field, self.far_region, self.far_step, o, d, t_a, t_b, trans, acc_rgb,
                              early_stop=self.early_stop, min_weight=self.min_weight, stats=self.stats)

    def _steps_this_round(self, started: int, live: int, remaining: int) -> int:
        """Steps per live ray in the next round: ``segment`` while all ``started`` rays of the chunk march, then
        as many more as the finished rays free (the first round's samples, so its memory), at most 16 segments
        and not past the longest ray's end. Each round costs a fixed number of kernel launches and host syncs
        besides its samples: a GPU with a whole view in one chunk and a few sky rays marching the whole
        diagonal spent almost all of its time in those (the 1.2 km city: 64 rounds of 32 steps, 10 s a view on
        an H100 at any resolution). Only where rays stop changes: by at most one round's steps after their
        transmittance fell below ``early_stop``."""
        grow = max(1, min(16, started // max(1, live)))
        whole = -(-max(1, remaining) // self.segment) * self.segment
        return max(self.segment, min(self.segment * grow, whole))

    def _march_segment(self, k0, ks, o, d, t0, dt, n_steps, tau_in, acc_rgb, acc_wt, acc_w,
                       acc_half) -> torch.Tensor:
        """Advance the live rays by steps k0 .. k0 + len(ks) - 1 (a whole number of ``segment`` blocks); updates
        the accumulators in place and returns the optical depth behind the round. All inputs are per live ray
        (A, ...); ``tau_in`` (A,) float64 is the optical depth in front of the round (transmittance exp(-tau_in));
        ``acc_w``, ``acc_wt`` are float64; ``acc_half`` (A, 2) holds the distances where the accumulated opacity
        reached 0.5 and FRINGE_OPACITY (0 until it does).

        A round is composited as its ``segment``-step blocks would be one after the other: the transmittance
        from float64 sums of the optical depth (SDF intervals: -log(1 - α)) chained block to block, the
        accumulators summed block by block, and a ray whose transmittance fell to ``early_stop`` at the end of a
        block takes nothing from the blocks after it. A ray's result therefore does not depend on the round
        length, which depends on how many rays of its chunk are still live: a NaN or Inf region that ended some
        rays sooner or later changed rays that never crossed it by up to 1e-4 (tests/stability)."""
        k = k0 + ks  # (K,)
        n_k = k.shape[0]
        valid = k[None, :] < n_steps[:, None]  # (A, K)
        t_mid = torch.addcmul(t0[:, None], k[None, :] + 0.5, dt[:, None])  # (A, K) interval midpoints
        occ = valid & self.occupancy.query_rays(o, d, t_mid) if self.occupancy is not None else valid
        flat = torch.nonzero(occ.reshape(-1)).flatten()
        if flat.numel() == 0:
            return tau_in
        n_live = occ.shape[0]
        if self.kind == "density":
            rows = flat // n_k
            pts = torch.addcmul(o[rows], t_mid.reshape(-1)[flat][:, None], d[rows])
            self.stats["geometry_points"] += pts.shape[0]
            sigma = torch.zeros(n_live * n_k, device=o.device)
            sigma[flat] = self.field.geometry(pts).reshape(-1).float()
            tau = optical_depth(sigma.reshape(n_live, n_k), dt[:, None])
            alpha = -torch.expm1(-tau)
            tau = tau.double()
            f = None
        else:
            ends = torch.zeros(n_live, n_k + 1, dtype=torch.bool, device=o.device)
            ends[:, :-1] |= occ
            ends[:, 1:] |= occ
            eflat = torch.nonzero(ends.reshape(-1)).flatten()
            rows = eflat // (n_k + 1)
            cols = eflat - rows * (n_k + 1)
            t_end = torch.addcmul(t0[rows], cols.float() + k0, dt[rows])
            pts = torch.addcmul(o[rows], t_end[:, None], d[rows])
            self.stats["geometry_points"] += pts.shape[0]
            f = torch.full((n_live * (n_k + 1),), _FAR_SDF, device=o.device)
            f[eflat] = self.field.geometry(pts).reshape(-1).float()
            f = f.reshape(n_live, n_k + 1)
            alpha = alpha_from_sdf(f[:, :-1], f[:, 1:], self.inv_s) * occ
            tau = -torch.log1p(-alpha.double())                       # inf where α = 1
        blocks = (n_live, n_k // self.segment, self.segment)
        tau, alpha = tau.reshape(blocks), alpha.reshape(blocks)
        # optical depth in front of each block and behind the last (a sequential float64 sum, as block by block)
        fronts = torch.cumsum(torch.cat([tau_in[:, None], tau.sum(-1)], dim=-1), dim=-1)        # (A, B + 1)
        live = fronts[:, :-1] < self._stop_tau                                                # (A, B)
        trans = torch.exp(-(fronts[:, :-1, None] + exclusive_cumsum(tau))).float()              # (A, B, S)
        w = torch.where(live[..., None], trans * alpha, 0.0)                                    # (A, B, S)
        tau_in = fronts.gather(1, live.sum(-1, keepdim=True)).squeeze(1)   # behind the last block it marched
        w_before = torch.cumsum(torch.cat([acc_w[:, None], w.sum(-1).double()], dim=-1), dim=-1)  # (A, B + 1)
        wt_after = torch.cumsum(torch.cat([acc_wt[:, None], (w * t_mid.reshape(blocks)).sum(-1).double()],
                                          dim=-1), dim=-1)
        if acc_half is not None:
            after = (w_before[:, :-1, None] + torch.cumsum(w, dim=-1, dtype=torch.float64)).reshape(n_live, n_k)
        acc_w.copy_(w_before[:, -1])
        acc_wt.copy_(wt_after[:, -1])
        w = w.reshape(n_live, n_k)
        for slot, level in enumerate((0.5, FRINGE_OPACITY) if acc_half is not None else ()):
            crossing = (after >= level) & (after - w < level)
            rows_x, cols_x = torch.nonzero(crossing, as_tuple=True)
            if rows_x.numel():
                before = (after - w)[rows_x, cols_x]
                frac = ((level - before) / w[rows_x, cols_x].clamp(min=1e-12)).clamp(0.0, 1.0).float()
                acc_half[rows_x, slot] = t_mid[rows_x, cols_x] + (frac - 0.5) * dt[rows_x]
        sflat = torch.nonzero((w > self.min_weight).reshape(-1)).flatten()
        if sflat.numel():
            rows = sflat // n_k
            self.stats["radiance_points"] += rows.numel()
            dirs = d[rows]
            x = torch.addcmul(o[rows], self._colour_distance(sflat, t_mid, f, dt)[:, None], dirs)
            c = torch.nan_to_num(self.field.radiance(x, dirs).float().reshape(-1, 3), nan=0.0, posinf=1.0,
                                 neginf=0.0)                          # a NaN colour sample counts as black
            acc_rgb.index_add_(0, rows, w.reshape(-1)[sflat][:, None] * c)
        return tau_in

    def _colour_distance(self, flat: torch.Tensor, t_mid: torch.Tensor, f: torch.Tensor | None,
                         dt: torch.Tensor) -> torch.Tensor:
        """(M,) distance along the ray at which the samples ``flat`` (indices into the round's (A, K) grid) take
        their colour: a density field's interval midpoint (as its trainer samples it), an SDF interval's weight
        centre (:func:`~.compositing.sdf_weight_centre`; ``f`` (A, K + 1) the endpoint SDFs)."""
        t = t_mid.reshape(-1)[flat]
        if f is None:
            return t
        n_k = t_mid.shape[1]
        rows, cols = flat // n_k, flat % n_k
        centre = sdf_weight_centre(f[rows, cols], f[rows, cols + 1], self.inv_s)
        return t + (centre - 0.5) * dt[rows]

    # ------------------------------------------------------------------ cameras
    @torch.no_grad()
    def render(self, cameras, index: int, *, crossings: bool = False) -> dict[str, np.ndarray]:
        """Render camera ``index``: ``{"rgb": (H, W, 3), "depth", "surface_depth", "fringe_depth", "opacity":
        (H, W)}`` float32 numpy, top row first; rgb in [0, 1] with the background composited (``crossings``: see
        :meth:`render_rays`)."""
        origins, dirs = cameras.rays(index)
        h, w = cameras.height, cameras.width
        out = {k: v.cpu() for k, v in self.render_rays(origins.reshape(-1, 3), dirs.reshape(-1, 3),
                                                        crossings=crossings).items()}
        return {"rgb": out["rgb"].reshape(h, w, 3).numpy().astype(np.float32),
                "depth": out["depth"].reshape(h, w).numpy().astype(np.float32),
                "surface_depth": out["surface_depth"].reshape(h, w).numpy().astype(np.float32),
                "fringe_depth": out["fringe_depth"].reshape(h, w).numpy().astype(np.float32),
                "opacity": out["opacity"].reshape(h, w).numpy().astype(np.float32)}

    def time_frames(self, cameras, indices=None) -> dict[str, float]:
        """Render the given camera indices and return ``{"seconds_per_frame", "fps", "frames"}`` (median)."""
        indices = list(range(len(cameras))) if indices is None else list(indices)
        times = []
        if self.device.type == "cuda" and indices:       # warm-up (kernels, allocator) is not timed
            self.render(cameras, indices[0])
        for i in indices:
            synchronize(self.device)
            start = time.perf_counter()
            self.render(cameras, i)
            synchronize(self.device)
            times.append(time.perf_counter() - start)
        spf = float(np.median(times))
        return {"seconds_per_frame": spf, "fps": 1.0 / spf if spf > 0 else math.inf, "frames": len(times)}
