"""An Instant-NGP NeRF snapshot as a Field, evaluated in plain PyTorch (no tiny-cuda-nn, no CUDA needed).

This module owns :class:`NgpField`: the forward model of instant-ngp's ``NerfNetwork``
(docs/formats.md §1.4–1.7) in the user's world frame (§1.8, :mod:`.frames`), the snapshot's
occupancy grid (§1.9) and the choice of the foreground box.

Forward model for world points x (N, 3) and unit directions of travel d (N, 3):

* ``x_net = frame.world_to_net(x)``; ``h = DensityMLP(HashGrid(x_net))`` (16 raw outputs);
* ``sigma_world = exp(h0) * scale`` (σ per ngp unit times ngp units per world unit), set to 0 where the
  snapshot's density grid marks the cell empty (instant-ngp never samples there either) and outside the
  network cube;
* ``rgb = sigmoid(RgbMLP([h0..h15, SH4(d_ngp), latent, 1-padding])[:3])``; HDR snapshots use
  ``exp(clamp(v, -10, 10))`` and are shown as instant-ngp displays them: ``srgb(clamp(v * 2^exposure))``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from neuras_distill.components.tcnn import HashGridEncoding, TcnnMLP, sh_encode_deg4
from neuras_distill.errors import require
from neuras_distill.fields.base import evaluate_chunked
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.far_region import FarRegion
from neuras_distill.render.occupancy import OccupancyGrid

from .frames import NgpFrame
from .snapshot import GRID_SIZE, NgpSnapshot

#: instant-ngp's mesh export threshold on the raw density output h0 = ln σ_ngp (§1.10).
NGP_MESH_LOG_DENSITY = 2.5
#: instant-ngp's occupancy threshold on optical thickness σ_ngp · √3/1024 (NERF_MIN_OPTICAL_THICKNESS).
NGP_MIN_OPTICAL_THICKNESS = 0.01


def _srgb(linear: torch.Tensor) -> torch.Tensor:
    linear = linear.clamp(0.0, 1.0)
    return torch.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear.clamp_min(1e-12) ** (1 / 2.4) - 0.055)


class NgpField(torch.nn.Module):
    """A trained instant-ngp NeRF as a neuras-distill density field (world frame of the user's data).

    Args:
        snapshot: a validated :class:`~.snapshot.NgpSnapshot`.
        foreground_box: (2, 3) world box overriding the automatic foreground box.
        latent_view: which training image's per-image latent code to render with (instant-ngp renders with
            view 0), or ``"mean"``.
        chunk: points per evaluation chunk (bounds memory).

    Field members: ``kind = "density"``, ``aabb`` (2, 3) world foreground box, ``geometry``, ``radiance``,
    ``background_color`` (3,), ``cameras`` (training cameras, world frame) or None, ``surface_level``
    (σ_world of instant-ngp's mesh threshold), ``unbounded``, ``far_region`` (when unbounded: the network cube
    beyond the box), ``occupancy_grid(resolution)``.
    """

    kind = "density"

    def __init__(self, snapshot: NgpSnapshot, *, foreground_box=None, latent_view: int | str = 0,
                 chunk: int = 2**16):
        super().__init__()
        s = snapshot
        self.snapshot_info = {"training_step": s.training_step, "aabb_scale": s.aabb_scale,
                              "grid": {"n_levels": s.grid.n_levels, "n_features_per_level": s.grid.n_features_per_level,
                                       "log2_hashmap_size": s.grid.log2_hashmap_size,
                                       "base_resolution": s.grid.base_resolution,
                                       "per_level_scale": s.grid.per_level_scale},
                              "params_type": s.params_type, "is_hdr": s.is_hdr, "notes": list(s.notes)}
        self.frame = NgpFrame(scale=s.scale, offset=tuple(s.offset), aabb_scale=float(s.aabb_scale),
                              from_mitsuba=s.from_mitsuba)
        self.chunk = int(chunk)
        self.is_hdr = s.is_hdr
        self.exposure = s.exposure
        self.encoding = HashGridEncoding(s.grid, torch.from_numpy(s.grid_params))
        dm, rm = s.density_mlp, s.rgb_mlp
        self.density_mlp = TcnnMLP(s.grid.n_output_dims(), dm.width, dm.n_hidden_layers, dm.n_out,
                                   params=torch.from_numpy(s.density_params))
        self.rgb_mlp = TcnnMLP(rm.n_in, rm.width, rm.n_hidden_layers, rm.n_out,
                               params=torch.from_numpy(s.rgb_params), output_alignment=rm.output_alignment)
        self.n_density_out = rm.n_in - s.dir_pad
        self.n_extra = s.n_extra_dims
        self.dir_pad = s.dir_pad
        latent = torch.zeros(s.n_extra_dims)
        if s.n_extra_dims and s.extra_dims is not None:
            if latent_view == "mean":
                latent = torch.from_numpy(s.extra_dims.mean(0))
            else:
                require(0 <= int(latent_view) < len(s.extra_dims),
                        f"latent view {latent_view} does not exist; the snapshot has {len(s.extra_dims)} images")
                latent = torch.from_numpy(s.extra_dims[int(latent_view)])
        self.register_buffer("latent", latent.float())
        bg = s.background_color
        self.background_color = torch.tensor(bg[:3], dtype=torch.float32).clamp(0.0, 1.0)
        if self.is_hdr:
            self.background_color = _srgb(self.background_color * 2.0**self.exposure)
        # instant-ngp's own mesh threshold, converted to density per world unit
        self.surface_level = math.exp(NGP_MESH_LOG_DENSITY) * self.frame.scale

        self._occ = None  # (C, 128, 128, 128) bool, ngp axes
        self._occupancy_cache: dict = {}
        if s.density_grid is not None:
            g = torch.from_numpy(s.density_grid)
            thresh = min(NGP_MIN_OPTICAL_THICKNESS, float(g[0].clamp_min(0).mean()))
            self._occ = g > thresh
        self.occupied_fraction = float(self._occ.float().mean()) if self._occ is not None else None

        self.aabb, self.unbounded, self.foreground_reason = self._foreground(s, foreground_box)
        self.far_region = self._far_region(s) if self.unbounded else None
        self.cameras = self._cameras(s)

    # ------------------------------------------------------------------ field contract
    def raw(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) world points -> (N, n_density_out) raw density-MLP outputs (h0 = ln σ_ngp)."""
        x_net = self.frame.world_to_net(x.float())
        return self.density_mlp(self.encoding(x_net.clamp(0.0, 1.0)))

    def _inside(self, x: torch.Tensor) -> torch.Tensor:
        x_net = self.frame.world_to_net(x.float())
        return ((x_net >= 0.0) & (x_net <= 1.0)).all(dim=-1)

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) world points -> (N,) σ per world unit (0 in cells the density grid marks empty)."""
        def run(xc):
            h0 = self.raw(xc)[:, 0]
            sigma = torch.exp(h0.clamp(max=80.0)) * self.frame.scale
            keep = self._inside(xc)
            if self._occ is not None:
                keep = keep & self.occupied(xc)
            return torch.where(keep, sigma, torch.zeros_like(sigma))

        with torch.no_grad():
            return evaluate_chunked(run, x, chunk=self.chunk)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3) world points, d (N, 3) unit directions of travel (world) -> (N, 3) colour in [0, 1]."""
        def run(xc, dc):
            h = self.raw(xc)[:, : self.n_density_out]
            d_ngp = torch.nn.functional.normalize(self.frame.world_dirs_to_ngp(dc.float()), dim=-1)
            parts = [h, sh_encode_deg4(d_ngp)]
            if self.n_extra:
                parts.append(self.latent.to(xc.device).expand(xc.shape[0], -1))
            width = sum(p.shape[1] for p in parts)
            pad = self.rgb_mlp_in - width
            if pad > 0:
                parts.append(torch.ones(xc.shape[0], pad, device=xc.device))
            v = self.rgb_mlp(torch.cat(parts, dim=1))[:, :3]
            if self.is_hdr:
                return _srgb(torch.exp(v.clamp(-10.0, 10.0)) * 2.0**self.exposure)
            return torch.sigmoid(v)

        with torch.no_grad():
            return evaluate_chunked(run, x, d, chunk=self.chunk)

    @property
    def rgb_mlp_in(self) -> int:
        return self.n_density_out + self.dir_pad

    # ------------------------------------------------------------------ occupancy
    def occupied(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) world points -> (N,) bool: the snapshot's density grid marks the cell occupied
        (smallest cascade containing the point, as instant-ngp looks it up). All True without a grid."""
        if self._occ is None:
            return torch.ones(x.shape[0], dtype=torch.bool, device=x.device)
        p = self.frame.world_to_ngp(x.float()) - 0.5
        occ = self._occ.to(x.device)
        n_casc = occ.shape[0]
        m = p.abs().amax(dim=-1)
        _, e = torch.frexp(m.clamp_min(1e-30))
        cascade = (e + 1).clamp(min=0)
        inside = cascade < n_casc
        cascade = cascade.clamp(max=n_casc - 1).long()
        size = torch.pow(2.0, cascade.float())
        idx = ((p / size[:, None] + 0.5) * GRID_SIZE).floor().long().clamp(0, GRID_SIZE - 1)
        return occ[cascade, idx[:, 0], idx[:, 1], idx[:, 2]] & inside

    def occupancy_grid(self, resolution: int = 128, samples: int = 3) -> OccupancyGrid | None:
        """An :class:`OccupancyGrid` over ``aabb`` (world) that contains every cell the snapshot's density grid
        marks occupied (``samples``^3 probes per cell, then dilated by one cell), or None without a grid."""
        if self._occ is None:
            return None
        key = (int(resolution), int(samples))
        if key not in self._occupancy_cache:  # every renderer asks; the answer never changes
            self._occupancy_cache[key] = self._resample_occupancy(*key)
        return self._occupancy_cache[key]

    def _resample_occupancy(self, resolution: int, samples: int) -> OccupancyGrid:
        r = int(resolution)
        lo, hi = self.aabb[0], self.aabb[1]
        cell = (hi - lo) / r
        offs = (torch.arange(samples, dtype=torch.float32) + 0.5) / samples
        sub = torch.stack(torch.meshgrid(offs, offs, offs, indexing="ij"), dim=-1).reshape(-1, 3)
        axes = [torch.arange(r, dtype=torch.float32) for _ in range(3)]
        base = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
        occ = torch.zeros(base.shape[0], dtype=torch.bool)
        for s in sub:
            occ |= evaluate_chunked(lambda b, s=s: self.occupied(lo + (b + s) * cell), base, chunk=2**20)
        occ = occ.reshape(r, r, r)
        occ = torch.nn.functional.max_pool3d(occ[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0
        return OccupancyGrid(self.aabb, occ)

    # ------------------------------------------------------------------ foreground box and cameras
    def _occupied_box_ngp(self, cascade: int = 0):
        """ngp-space bounding box of occupied cells of one cascade (dilated by two cells), or None."""
        occ = self._occ[cascade]
        if not bool(occ.any()):
            return None
        idx = occ.nonzero()
        size = 2.0**cascade
        lo = 0.5 + size * ((idx.min(0).values.double() - 2) / GRID_SIZE - 0.5)
        hi = 0.5 + size * ((idx.max(0).values.double() + 3) / GRID_SIZE - 0.5)
        return lo.clamp(0.5 - size / 2, 0.5 + size / 2), hi.clamp(0.5 - size / 2, 0.5 + size / 2)

    def _foreground(self, s: NgpSnapshot, override):
        half = 0.5 * s.aabb_scale
        full = (torch.full((3,), 0.5 - half, dtype=torch.float64), torch.full((3,), 0.5 + half, dtype=torch.float64))
        if override is not None:
            box = torch.as_tensor(override, dtype=torch.float32).reshape(2, 3)
            require(bool(torch.isfinite(box).all()) and bool((box[0] < box[1]).all()),
                    f"foreground box must be [min, max] with min < max, got {box.tolist()}")
            reason = "given by the user"
        else:
            lo, hi = full
            reason = "the network cube" if s.aabb_scale == 1 else "cascade 0 of the density grid (the unit cube)"
            if s.aabb_scale > 1:
                lo, hi = torch.zeros(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64)
            if s.render_aabb is not None:
                rlo, rhi = (torch.tensor(v, dtype=torch.float64) for v in s.render_aabb)
                if bool((rlo > full[0] + 1e-6).any() or (rhi < full[1] - 1e-6).any()):
                    lo, hi = torch.maximum(full[0], rlo), torch.minimum(full[1], rhi)
                    reason = "the snapshot's render box"
            if self._occ is not None:
                occ_box = self._occupied_box_ngp(0)
                if occ_box is not None:
                    lo, hi = torch.maximum(lo, occ_box[0]), torch.minimum(hi, occ_box[1])
                    reason += ", shrunk to the occupied cells"
            require(bool((lo < hi).all()), "the snapshot's render box holds no occupied cells; "
                                           "give a foreground box that holds the scene")
            box = self.frame.ngp_box_to_world(lo.tolist(), hi.tolist())
        unbounded = False
        if self._occ is not None and s.aabb_scale > 1:
            # occupied cells whose centre lies outside the foreground box -> content outside it
            ngp_box = self.frame.world_box_to_ngp(box)
            for c in range(self._occ.shape[0]):
                idx = self._occ[c].nonzero().double()
                if idx.numel() == 0:
                    continue
                centres = 0.5 + 2.0**c * ((idx + 0.5) / GRID_SIZE - 0.5)
                outside = ((centres < ngp_box[0]) | (centres > ngp_box[1])).any(dim=1)
                if bool(outside.any()):
                    unbounded = True
                    break
        return box.float(), unbounded, reason

    def _far_region(self, s: NgpSnapshot) -> FarRegion:
        """The network cube beyond the foreground box (instant-ngp's outer cascades, ``aabb_scale`` > 1), which the
        teacher marches in front of and behind the box (``render/far_region.py``). The field is zero outside the
        cube, so the far plane only has to lie beyond it: twice the cube's diagonal (world units) covers a camera
        anywhere within one diagonal of the cube. Sampling is linear out to half the cube's side and uniform in
        disparity beyond: a pivot at the foreground box's size spaced the samples a wall in the outer cascade
        needs ten times too far apart (the cube is bounded, not contracted)."""
        side = float(s.aabb_scale) / float(self.frame.scale)
        return FarRegion(near=0.0, far=2.0 * math.sqrt(3.0) * side, pivot=0.5 * side)

    def _cameras(self, s: NgpSnapshot) -> Cameras | None:
        if not s.cameras:
            return None
        w, h = s.cameras[0].width, s.cameras[0].height
        c2w, fx, fy, cx, cy = [], [], [], [], []
        for c in s.cameras:
            sx, sy = w / c.width, h / c.height  # images of another size: scale the intrinsics to the first's
            c2w.append(self.frame.ngp_c2w_to_world(c.c2w_ngp))
            fx.append(c.fx * sx)
            fy.append(c.fy * sy)
            cx.append(c.cx * sx)
            cy.append(c.cy * sy)
        try:
            return Cameras(c2w=torch.as_tensor(np.stack(c2w), dtype=torch.float32), fx=fx, fy=fy, cx=cx, cy=cy,
                           width=w, height=h)
        except ValueError as exc:
            self.snapshot_info["notes"].append(f"stored cameras not usable: {exc}")
            return None

    def __repr__(self) -> str:
        g = self.encoding.config
        return (f"NgpField(L{g.n_levels} F{g.n_features_per_level} T2^{g.log2_hashmap_size} "
                f"aabb_scale={self.snapshot_info['aabb_scale']}, aabb={self.aabb.tolist()}, "
                f"cameras={len(self.cameras) if self.cameras is not None else 0})")
