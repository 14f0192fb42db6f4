#!/usr/bin/env python3
"""Fit a small Instant-NGP NeRF to an embedded scene (the bunny by default) and save it as an instant-ngp
``.ingp`` snapshot.

The result, ``tests/data/ngp/bunny.ingp`` (or ``<scene>.ingp`` with ``--scene``), is a committed test
fixture: a field with real training artefacts (soft surfaces, floaters, noise in empty space) for
``neuras-distill from-ngp``, in exactly the layout instant-ngp writes (docs/formats.md §1), so the
loader is exercised on what a real snapshot holds.

What it does (all in instant-ngp's "ngp" space, §1.8, aabb_scale 1, so network space = ngp space):

* **Data.** The scene's ``default_cameras(48, 192, 108)`` orbit, rendered once by the volume renderer (192
  steps) over the scene's white background. Nothing is cached. The same cameras, converted with
  ``NgpFrame.world_c2w_to_ngp``, are stored as the snapshot's dataset.
* **Frame.** ``scale``/``offset`` as a transforms.json ``aabb`` would set them: the scene box grown by
  ``FRAME_MARGIN`` of its largest side on every side, ``scale = 1 / largest side``, centre at 0.5. With
  this margin a few cube corners (4,620 of 128^3 density-grid cells) are seen by no training camera.
* **Model.** instant-ngp's ``configs/nerf/base.json`` with a 2^14 hash table: hash grid L=8, F=4,
  N_min=16, ``per_level_scale`` not written (instant-ngp's automatic 2.0 for aabb_scale 1); density MLP
  32 -> 64 -> 16 and rgb MLP 32 -> 64 -> 64 -> 3 (tcnn layout, no biases);
  ``sigma = exp(h0)`` per ngp unit, ``rgb = sigmoid(rgbMLP([h0..h15, SH4(d_ngp)])[:3])``.
* **Training, instant-ngp style.** Random rays from all training pixels (pixel centres); samples every
  ``TRAIN_STEP`` along the ray through the unit cube with a jittered start, skipping cells its own 128^3
  density grid marks empty; the no-gradient pre-pass finds where each ray's transmittance drops below 1e-4
  and only samples before that are trained (instant-ngp's compaction); the number of rays adapts so that
  about ``--batch-samples`` samples are trained per step (instant-ngp's ``measured_batch_size``). L2 loss
  (instant-ngp's NeRF default). Background: by default a random colour per ray with the target
  re-composited over it using the teacher's opacity as alpha, exactly as instant-ngp trains on RGBA images
  (``random_bg_color``); with a fixed white background the model may keep white fog for free, which costs
  many samples per ray (``--background white`` does that). The snapshot's rendering background is the
  scene's white. tcnn's Adam (lr 1e-2, betas 0.9/0.99, eps 1e-15, l2_reg 1e-6
  on the MLP weights, zero-gradient hash entries skipped, per-parameter step counts) and the Ema(0.95)
  wrapper: the saved parameters are the EMA weights, as instant-ngp saves them.
* **Density grid** (§1.9): optical thickness ``sigma * sqrt(3)/1024``, −1 for cells no training camera
  sees (``mark_untrained_density_grid``); updated with the EMA weights on instant-ngp's schedule (every step
  at first, then every 2, 3, ... up to every 16 steps) by sampling random points in random cells (visible
  cells, plus cells above 0.01 after step 256), taking the max per cell and merging as
  ``max(old * 0.95, new)``. instant-ngp samples 128^3 (then 2 x 128^3 / 4) points per update; on one CPU
  thread we sample 128^3 once at step 0, then 128^3 / 16 per update (half of them in occupied cells after
  step 256).

Deviations from instant-ngp, for CPU time: the marching step is ``sqrt(3)/512`` (2x instant-ngp's finest
step), fewer density-grid samples per update (above), batches of ~2^15 samples instead of 2^18, and a few
minutes of training instead of tens of thousands of steps.

The committed fixture came from the defaults (seed 0, 9 minutes on one thread: 747 steps): 1.8 MiB,
about 35.5 dB against the scene on two held-out views, a soft surface, hundreds of small floaters, and
occupied density-grid cells out to the walls of the cube.

``tests/data/ngp/ball.ingp`` is the ``gradient-ball`` scene (a density ball with a soft fringe, a colour
gradient and its own helix of cameras, :mod:`neuras_distill.scenes.gradient_ball`), made with
``--scene gradient-ball --out tests/data/ngp/ball.ingp --minutes 4 --seed 0 --max-bytes 2000000`` on a
shared 2-core machine: 429 steps in 4.0 min (repeated bit-identically with ``--steps 429``), 38.7 / 39.8 dB
against the scene on the two held-out views, 1.18 MiB (the first write, with density-grid values below 1e-4
flushed, was 2.04 MB, so values below the occupancy threshold 0.01 were flushed too). The ball came out as
trained NeRFs do: a shell (σ at the centre ~7 per unit against ~40 just under the surface, 18 % of the
points within 0.4 of the centre at σ = 0), a silhouette sharper than the scene's and ragged at the scale of
density-grid cells (the occupancy threshold, σ ≈ 3.3 per world unit here, cuts the fringe's outer tail where
the scene's σ < 3.5, i.e. beyond the visible radius), speckle noise on the surface, and no floaters (σ > 0
nowhere beyond 0.06 outside the visible radius, above the mesh level nowhere beyond 0.04).

Usage:
    python scripts/make_ngp_fixture.py [--scene bunny] [--out tests/data/ngp/<scene>.ingp] [--minutes 9]
                                       [--seed 0] [--steps N] [--max-bytes 2097152]

``--steps`` fixes the number of training steps (otherwise training stops after ``--minutes``; the number of
steps done is printed so that a run can be repeated with ``--steps``: bit-identical on the same machine and
torch build with one thread).
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))  # run from a checkout without installing
if importlib.util.find_spec("neuras_distill_adapters") is None:  # not installed: adapters/ is that package
    _spec = importlib.util.spec_from_file_location("neuras_distill_adapters", ROOT / "adapters" / "__init__.py",
                                                   submodule_search_locations=[str(ROOT / "adapters")])
    sys.modules["neuras_distill_adapters"] = importlib.util.module_from_spec(_spec)
    _spec.loader.exec_module(sys.modules["neuras_distill_adapters"])

from neuras_distill.components.tcnn import (HashGridConfig, HashGridEncoding, TcnnMLP,  # noqa: E402
                                            ngp_per_level_scale, sh_encode_deg4)
from neuras_distill.render.volume import VolumeRenderer  # noqa: E402
from neuras_distill.scenes.synthetic import make_scene  # noqa: E402
from neuras_distill_adapters.instant_ngp.field import NgpField  # noqa: E402
from neuras_distill_adapters.instant_ngp.frames import NgpFrame  # noqa: E402
from neuras_distill_adapters.instant_ngp.snapshot import (NgpCamera, build_snapshot_tree,  # noqa: E402
                                                          read_snapshot, write_snapshot)

DEFAULT_OUT = ROOT / "tests" / "data" / "ngp" / "bunny.ingp"
MAX_FILE_BYTES = 2 * 1024 * 1024

# data
N_VIEWS, WIDTH, HEIGHT = 48, 192, 108
TEACHER_STEPS = 192
HELD_OUT = (25, 61)          # default_cameras(96) indices: between training views (those are the even ones)
FRAME_MARGIN = 0.25          # transforms.json-style aabb: scene box grown by this * its largest side per side

# model (instant-ngp configs/nerf/base.json with log2_hashmap_size 14)
AABB_SCALE = 1
N_LEVELS, N_FEATURES, LOG2_T, BASE_RES = 8, 4, 14, 16

# instant-ngp constants (src/testbed_nerf.cu)
GRID_RES = 128
MIN_CONE_STEPSIZE = math.sqrt(3.0) / 1024   # density-grid values are sigma * this (optical thickness)
MIN_OPTICAL_THICKNESS = 0.01
T_EPS = 1e-4                                 # transmittance below which a ray is done (compaction)
GRID_DECAY = 0.95

# our training
TRAIN_STEP = math.sqrt(3.0) / 512            # marching step in ngp units (2x instant-ngp's finest step)
ROUND = 16                                   # samples per ray per round of the no-gradient pre-pass
LR, BETAS, EPS, L2_REG, EMA_DECAY = 1e-2, (0.9, 0.99), 1e-15, 1e-6, 0.95
FLUSH_BELOW = 1e-4                           # density-grid values in [0, this) are written as 0


def log(msg: str) -> None:
    print(msg, flush=True)


# ---------------------------------------------------------------------------------------------- model
class _TruncExp(torch.autograd.Function):
    """exp(x) with the derivative clamped to exp(clamp(x, -15, 15)) (instant-ngp's Exponential activation)."""

    @staticmethod
    def forward(ctx, x):
        ctx.save_for_backward(x)
        return torch.exp(x)

    @staticmethod
    def backward(ctx, g):
        (x,) = ctx.saved_tensors
        return g * torch.exp(x.clamp(-15.0, 15.0))


class NgpModel(torch.nn.Module):
    """instant-ngp's NerfNetwork in plain PyTorch: points and unit directions in ngp space."""

    def __init__(self):
        super().__init__()
        cfg = HashGridConfig(n_levels=N_LEVELS, n_features_per_level=N_FEATURES, log2_hashmap_size=LOG2_T,
                             base_resolution=BASE_RES,
                             per_level_scale=ngp_per_level_scale(AABB_SCALE, BASE_RES, N_LEVELS))
        self.encoding = HashGridEncoding(cfg)
        self.density_mlp = TcnnMLP(cfg.n_output_dims(), 64, 1, 16)
        self.rgb_mlp = TcnnMLP(16 + 16, 64, 2, 3)

    def raw(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) ngp points -> (N, 16) density-MLP outputs (h0 = ln sigma)."""
        return self.density_mlp(self.encoding(x))

    def sigma(self, x: torch.Tensor) -> torch.Tensor:
        return _TruncExp.apply(self.raw(x)[:, 0])

    def forward(self, x: torch.Tensor, d: torch.Tensor):
        """(N, 3) ngp points, (N, 3) unit ngp directions -> sigma (N,) per ngp unit, rgb (N, 3)."""
        h = self.raw(x)
        rgb = torch.sigmoid(self.rgb_mlp(torch.cat([h, sh_encode_deg4(d)], dim=1)))
        return _TruncExp.apply(h[:, 0]), rgb

    def param_groups(self):
        """(matrix params, non-matrix params) as tcnn's Adam sees them."""
        return [self.density_mlp.params, self.rgb_mlp.params], [self.encoding.params]


class TcnnAdam:
    """tiny-cuda-nn's Adam: per-parameter step counts, l2_reg on matrix weights, non-matrix (hash-grid)
    entries with an exactly zero gradient are skipped (sparse updates)."""

    def __init__(self, matrix, non_matrix, lr=LR, betas=BETAS, eps=EPS, l2_reg=L2_REG):
        self.groups = [(p, True) for p in matrix] + [(p, False) for p in non_matrix]
        self.lr, (self.b1, self.b2), self.eps, self.l2 = lr, betas, eps, l2_reg
        self.state = [(torch.zeros_like(p), torch.zeros_like(p), torch.zeros_like(p)) for p, _ in self.groups]

    @torch.no_grad()
    def step(self) -> None:
        for (p, is_matrix), (m, v, n) in zip(self.groups, self.state):
            if p.grad is None:
                continue
            g = p.grad
            if is_matrix:
                g = g + self.l2 * p
                mask = None
            else:
                mask = g != 0
            if mask is None:
                m.mul_(self.b1).add_(g, alpha=1 - self.b1)
                v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
                n.add_(1)
                lr = self.lr * torch.sqrt(1 - self.b2**n) / (1 - self.b1**n)
                p.sub_(lr * m / (v.sqrt() + self.eps))
            else:
                idx = mask.nonzero().flatten()
                gi = g[idx]
                mi = m[idx].mul_(self.b1).add_(gi, alpha=1 - self.b1)
                vi = v[idx].mul_(self.b2).addcmul_(gi, gi, value=1 - self.b2)
                ni = n[idx] + 1
                m[idx], v[idx], n[idx] = mi, vi, ni
                lr = self.lr * torch.sqrt(1 - self.b2**ni) / (1 - self.b1**ni)
                p[idx] -= lr * mi / (vi.sqrt() + self.eps)
            p.grad = None


class Ema:
    """tcnn's Ema optimizer wrapper: debiased exponential moving average of the weights (what is saved)."""

    def __init__(self, model: NgpModel, ema_model: NgpModel, decay=EMA_DECAY):
        self.src = [p for p in model.parameters()]
        self.dst = [p for p in ema_model.parameters()]
        self.raw = [torch.zeros_like(p) for p in self.src]
        self.decay, self.t = decay, 0

    @torch.no_grad()
    def update(self) -> None:
        self.t += 1
        debias = 1.0 - self.decay**self.t
        for s, d, r in zip(self.src, self.dst, self.raw):
            r.mul_(self.decay).add_(s, alpha=1 - self.decay)
            d.copy_(r / debias)


# ---------------------------------------------------------------------------------------------- density grid
def visible_cells(cameras: list[NgpCamera]) -> torch.Tensor:
    """(128, 128, 128) bool [ix, iy, iz]: cells with a corner in front of and inside the image of at least
    one training camera (instant-ngp ``mark_untrained_density_grid``, pinhole cameras, min_count 1)."""
    axis = torch.arange(GRID_RES + 1, dtype=torch.float32) / GRID_RES
    corners = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1).reshape(-1, 3)
    seen = torch.zeros(corners.shape[0], dtype=torch.bool)
    for cam in cameras:
        m = torch.as_tensor(cam.c2w_ngp, dtype=torch.float32)
        rel = corners - m[:, 3]
        c = rel @ m[:, :3]  # camera coordinates: x right, y down, z forward
        front = c[:, 2] >= 1e-4 * rel.norm(dim=-1)
        z = c[:, 2].clamp_min(1e-12)
        u = (c[:, 0] / z * cam.fx + cam.cx) / cam.width
        v = (c[:, 1] / z * cam.fy + cam.cy) / cam.height
        seen |= front & (u > 0) & (u < 1) & (v > 0) & (v < 1)
    s = seen.reshape(GRID_RES + 1, GRID_RES + 1, GRID_RES + 1)
    out = torch.zeros(GRID_RES, GRID_RES, GRID_RES, dtype=torch.bool)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                out |= s[dx:dx + GRID_RES, dy:dy + GRID_RES, dz:dz + GRID_RES]
    return out


class DensityGrid:
    """instant-ngp's cascade-0 density grid: optical thickness per cell, -1 where no camera looks."""

    def __init__(self, visible: torch.Tensor):
        self.values = torch.where(visible, 0.0, -1.0).reshape(-1).float()  # [ix, iy, iz] flattened
        self.bits = torch.zeros_like(self.values, dtype=torch.bool)
        self.n_updates = 0

    def threshold(self) -> float:
        return min(MIN_OPTICAL_THICKNESS, float(self.values.clamp_min(0.0).mean()))

    @torch.no_grad()
    def update(self, model: NgpModel, n_uniform: int, n_nonuniform: int, gen: torch.Generator) -> None:
        idx = []
        vis = (self.values > -0.01).nonzero().flatten()
        if n_uniform:
            idx.append(vis[torch.randint(vis.numel(), (n_uniform,), generator=gen)])
        if n_nonuniform:
            occ = (self.values > MIN_OPTICAL_THICKNESS).nonzero().flatten()
            pool = occ if occ.numel() else vis
            idx.append(pool[torch.randint(pool.numel(), (n_nonuniform,), generator=gen)])
        idx = torch.cat(idx)
        cell = torch.stack([idx // GRID_RES**2, (idx // GRID_RES) % GRID_RES, idx % GRID_RES], dim=-1)
        pos = (cell.float() + torch.rand(idx.numel(), 3, generator=gen)) / GRID_RES
        sigma = torch.cat([model.sigma(pos[i:i + 2**16]) for i in range(0, pos.shape[0], 2**16)])
        thick = sigma * MIN_CONE_STEPSIZE
        new = torch.zeros_like(self.values).scatter_reduce(0, idx, thick, reduce="amax", include_self=True)
        self.values = torch.where(self.values < 0, self.values, torch.maximum(self.values * GRID_DECAY, new))
        self.bits = self.values > self.threshold()
        self.n_updates += 1

    def occupied_fraction(self) -> float:
        return float(self.bits.float().mean())


# ---------------------------------------------------------------------------------------------- marching
def ray_unit_cube(o: torch.Tensor, d: torch.Tensor):
    """Slab test against [0, 1]^3: t_near (>= 0), t_far, hit."""
    inv = 1.0 / torch.where(d.abs() < 1e-12, torch.full_like(d, 1e-12), d)
    t0, t1 = (0.0 - o) * inv, (1.0 - o) * inv
    near = torch.minimum(t0, t1).amax(dim=-1).clamp_min(0.0)
    far = torch.maximum(t0, t1).amin(dim=-1)
    return near, far, far > near


def march(model: NgpModel, grid: DensityGrid, o: torch.Tensor, d: torch.Tensor, jitter: torch.Tensor,
          bg: torch.Tensor):
    """Render rays (R, 3) ngp space: occupied samples, no-grad pre-pass for the compaction, then the
    (differentiable when grad is enabled) pass over the kept samples. Returns rgb (R, 3), opacity (R,),
    number of kept samples."""
    r = o.shape[0]
    near, far, hit = ray_unit_cube(o, d)
    n_steps = torch.where(hit, torch.ceil((far - near) / TRAIN_STEP), torch.zeros_like(far)).long()
    k_max = int(n_steps.max()) if r else 0
    if k_max == 0:
        return bg.expand(r, 3).clone(), torch.zeros(r), 0
    k = torch.arange(k_max, dtype=torch.float32)
    t = near[:, None] + (k[None, :] + jitter[:, None]) * TRAIN_STEP        # (R, K)
    valid = t < far[:, None]
    p = (o[:, None, :] + t[..., None] * d[:, None, :]).clamp(0.0, 1.0)     # (R, K, 3)
    cell = (p * GRID_RES).long().clamp(0, GRID_RES - 1)
    lin = (cell[..., 0] * GRID_RES + cell[..., 1]) * GRID_RES + cell[..., 2]
    occ = valid & grid.bits[lin]
    ray_idx, k_idx = occ.nonzero(as_tuple=True)                            # sorted by ray, then k
    if ray_idx.numel() == 0:
        return bg.expand(r, 3).clone(), torch.zeros(r), 0
    rank = (occ.cumsum(dim=1) - 1)[ray_idx, k_idx]
    n_occ = occ.sum(dim=1)

    # pre-pass (no gradient): how many occupied samples of each ray come before transmittance < T_EPS
    keep_n = torch.zeros(r, dtype=torch.long)
    tau_acc = torch.zeros(r)
    alive = n_occ > 0
    slots = torch.arange(ROUND)
    lo = 0
    with torch.no_grad():
        while bool(alive.any()):
            sel = ((rank >= lo) & (rank < lo + ROUND) & alive[ray_idx]).nonzero().flatten()
            if sel.numel() == 0:
                break
            rs, js = ray_idx[sel], rank[sel] - lo
            sig = torch.cat([model.sigma(p[rs[i:i + 2**16], k_idx[sel[i:i + 2**16]]])
                             for i in range(0, sel.numel(), 2**16)])
            tau = torch.zeros(r, ROUND).index_put((rs, js), sig * TRAIN_STEP)
            exists = alive[:, None] & (lo + slots[None, :] < n_occ[:, None])
            t_before = torch.exp(-(tau_acc[:, None] + tau.cumsum(dim=1) - tau))
            keep_n += (exists & (t_before > T_EPS)).sum(dim=1)
            tau_acc += tau.sum(dim=1)
            lo += ROUND
            alive = alive & (torch.exp(-tau_acc) > T_EPS) & (n_occ > lo)

    kept = rank < keep_n[ray_idx]
    rk, kk, jk = ray_idx[kept], k_idx[kept], rank[kept]
    n_kept = int(rk.numel())
    if n_kept == 0:
        return bg.expand(r, 3).clone(), torch.zeros(r), 0
    sigma, rgb = model(p[rk, kk], d[rk])
    m = int(keep_n.max())
    tau = torch.zeros(r, m).index_put((rk, jk), sigma * TRAIN_STEP)
    trans = torch.exp(-(tau.cumsum(dim=1) - tau))
    w = trans * -torch.expm1(-tau)
    opacity = w.sum(dim=1)
    color = torch.zeros(r, 3).index_add(0, rk, w[rk, jk][:, None] * rgb)
    return color + (1.0 - opacity)[:, None] * bg, opacity, n_kept


@torch.no_grad()
def render_view(model, grid, o, d, bg, chunk=4096):
    outs = []
    for i in range(0, o.shape[0], chunk):
        oc, dc = o[i:i + chunk], d[i:i + chunk]
        outs.append(march(model, grid, oc, dc, torch.full((oc.shape[0],), 0.5), bg)[0])
    return torch.cat(outs).clamp(0.0, 1.0)


def psnr(a, b) -> float:
    mse = float(((torch.as_tensor(a) - torch.as_tensor(b)) ** 2).mean())
    return 10.0 * math.log10(1.0 / max(mse, 1e-12))


# ---------------------------------------------------------------------------------------------- frame, data
def choose_frame(aabb: torch.Tensor) -> NgpFrame:
    """scale/offset as instant-ngp derives them from a transforms.json ``aabb`` (scale = 1 / largest side,
    offset puts the box centre at 0.5), for the scene box grown by FRAME_MARGIN of its largest side."""
    lo, hi = aabb[0].double(), aabb[1].double()
    side = float((hi - lo).max())
    lo, hi = lo - FRAME_MARGIN * side, hi + FRAME_MARGIN * side
    scale = 1.0 / float((hi - lo).max())
    centre = 0.5 * (lo + hi)
    offset = tuple(float(v) for v in (0.5 - centre * scale))
    return NgpFrame(scale=scale, offset=offset, aabb_scale=float(AABB_SCALE))


def ngp_rays(cameras, frame: NgpFrame, i: int):
    o, d = cameras.rays(i)
    o, d = o.reshape(-1, 3).double(), d.reshape(-1, 3).double()
    d_ngp = torch.nn.functional.normalize(frame.world_dirs_to_ngp(d), dim=-1)
    return frame.world_to_ngp(o).float(), d_ngp.float()


class TrainedField(torch.nn.Module):
    """The trained model as a world-frame density field with the same semantics as NgpField (sigma per world
    unit gated by the density grid and the unit cube), for the loader round-trip comparison."""

    kind = "density"

    def __init__(self, model, bits: torch.Tensor, frame: NgpFrame, aabb):
        super().__init__()
        self.model, self.bits, self.frame = model, bits, frame
        self.aabb = torch.as_tensor(aabb, dtype=torch.float32)
        self.background_color = torch.ones(3)

    def _gate(self, p):
        inside = ((p >= 0) & (p <= 1)).all(dim=-1) & ((p - 0.5).abs().amax(dim=-1) < 0.5)
        cell = (p * GRID_RES).floor().long().clamp(0, GRID_RES - 1)
        return inside & self.bits[(cell[:, 0] * GRID_RES + cell[:, 1]) * GRID_RES + cell[:, 2]]

    @torch.no_grad()
    def geometry(self, x):
        p = self.frame.world_to_ngp(x.float())
        sigma = torch.exp(self.model.raw(p.clamp(0.0, 1.0))[:, 0].clamp(max=80.0)) * self.frame.scale
        return torch.where(self._gate(p), sigma, torch.zeros_like(sigma))

    @torch.no_grad()
    def radiance(self, x, d):
        p = self.frame.world_to_ngp(x.float()).clamp(0.0, 1.0)
        dn = torch.nn.functional.normalize(self.frame.world_dirs_to_ngp(d.float()), dim=-1)
        return self.model(p, dn)[1]


# ---------------------------------------------------------------------------------------------- main
def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="bunny",
                    help="embedded scene to fit, as a density field (default bunny; e.g. gradient-ball)")
    ap.add_argument("--out", type=Path, default=None,
                    help=f"snapshot to write (default {DEFAULT_OUT.parent}/<scene>.ingp)")
    ap.add_argument("--minutes", type=float, default=9.0, help="wall-clock training budget (default 9)")
    ap.add_argument("--steps", type=int, default=None,
                    help="train exactly this many steps (overrides --minutes)")
    ap.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    ap.add_argument("--batch-samples", type=int, default=2**15,
                    help="trained samples per step the ray count adapts to (default 32768)")
    ap.add_argument("--background", choices=("random", "white"), default="random",
                    help="training background: a random colour per ray with the teacher's alpha, as "
                         "instant-ngp trains on RGBA images (default), or the scene's white")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--max-bytes", type=int, default=MAX_FILE_BYTES,
                    help=f"size limit of the snapshot; above it small density-grid values are flushed to 0 "
                         f"(default {MAX_FILE_BYTES:,})")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.out is None:
        args.out = DEFAULT_OUT.parent / f"{args.scene}.ingp"
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    gen = torch.Generator().manual_seed(args.seed)
    t_start = time.perf_counter()

    # ---- teacher images
    scene = make_scene(args.scene, kind="density")
    cams = scene.default_cameras(N_VIEWS, WIDTH, HEIGHT)
    held = scene.default_cameras(2 * N_VIEWS, WIDTH, HEIGHT)
    teacher = VolumeRenderer(scene, num_steps=TEACHER_STEPS)
    renders = [teacher.render(cams, i) for i in range(len(cams))]
    images = torch.stack([torch.from_numpy(r["rgb"]).reshape(-1, 3) for r in renders])
    alphas = torch.stack([torch.from_numpy(r["opacity"]).reshape(-1) for r in renders])
    del renders
    held_images = [torch.from_numpy(teacher.render(held, i)["rgb"]) for i in HELD_OUT]
    frame = choose_frame(scene.aabb)
    bg = torch.as_tensor(scene.background_color, dtype=torch.float32).reshape(3)
    log(f"teacher: {args.scene}, {len(cams)} views {WIDTH}x{HEIGHT} in {time.perf_counter() - t_start:.1f}s; "
        f"frame scale {frame.scale:.6f} offset {tuple(round(v, 6) for v in frame.offset)}")

    rays = [ngp_rays(cams, frame, i) for i in range(len(cams))]
    all_o = torch.cat([o for o, _ in rays])
    all_d = torch.cat([d for _, d in rays])
    all_rgb = images.reshape(-1, 3)
    all_alpha = alphas.reshape(-1, 1)
    ngp_cams = [NgpCamera(frame.world_c2w_to_ngp(cams.c2w[i].double().numpy()), float(cams.fx[i]),
                          float(cams.fy[i]), float(cams.cx[i]), float(cams.cy[i]), cams.width, cams.height)
                for i in range(len(cams))]

    # ---- model, optimizer, density grid
    model = NgpModel()
    ema_model = NgpModel()
    for p in ema_model.parameters():
        p.requires_grad_(False)
    ema_model.load_state_dict(model.state_dict())
    adam = TcnnAdam(*model.param_groups())
    ema = Ema(model, ema_model)
    grid = DensityGrid(visible_cells(ngp_cams))
    log(f"density grid: {int((grid.values < 0).sum())} of {GRID_RES**3} cells seen by no training camera "
        "(-1)")
    n_cells = GRID_RES**3
    grid.update(ema_model, n_cells, 0, gen)  # instant-ngp samples every cell-sized share at step 0

    # ---- training
    budget = args.minutes * 60.0
    t_train = time.perf_counter()
    rays_per_batch = 1024
    step, losses, samples = 0, [], []
    while True:
        elapsed = time.perf_counter() - t_train
        if (args.steps is not None and step >= args.steps) or (args.steps is None and elapsed >= budget):
            break
        skip = min(max(step // 16, 1), 16)
        if step > 0 and step % skip == 0:
            if step < 256:
                grid.update(ema_model, n_cells // 16, 0, gen)
            else:
                grid.update(ema_model, n_cells // 32, n_cells // 32, gen)
        sel = torch.randint(all_o.shape[0], (rays_per_batch,), generator=gen)
        jitter = torch.rand(rays_per_batch, generator=gen)
        if args.background == "random":
            # instant-ngp's random_bg_color for RGBA training images: a random colour behind each ray, the
            # target re-composited over it with the image's alpha (the teacher's opacity)
            ray_bg = torch.rand(rays_per_batch, 3, generator=gen)
            target = all_rgb[sel] + (1.0 - all_alpha[sel]) * (ray_bg - bg)
        else:
            ray_bg, target = bg, all_rgb[sel]
        pred, _, n_kept = march(model, grid, all_o[sel], all_d[sel], jitter, ray_bg)
        loss = ((pred - target) ** 2).mean()
        if n_kept:
            loss.backward()
            adam.step()
            ema.update()
        losses.append(float(loss.detach()))
        samples.append(n_kept)
        # instant-ngp: rays_per_batch = rays_per_batch * target / measured_batch_size (multiple of 128)
        wanted = rays_per_batch * args.batch_samples / max(n_kept, 1)
        rays_per_batch = int(min(max(wanted, 256), 16384)) // 128 * 128
        step += 1
        if step % 50 == 0:
            log(f"step {step:5d}  {time.perf_counter() - t_train:6.1f}s  loss {np.mean(losses[-50:]):.5f} "
                f"(~{-10 * math.log10(max(np.mean(losses[-50:]), 1e-12)):.2f} dB)  rays {rays_per_batch}  "
                f"samples {int(np.mean(samples[-50:]))}  occupied {grid.occupied_fraction():.2%}")
    train_s = time.perf_counter() - t_train
    grid.update(ema_model, n_cells // 32, n_cells // 32, gen)  # the stored grid goes with the stored weights
    log(f"trained {step} steps in {train_s:.1f}s ({train_s / 60:.2f} min); density grid updated "
        f"{grid.n_updates} times, {grid.occupied_fraction():.2%} occupied")

    # ---- own renders of the held-out views (ngp space, the training marcher)
    for k, i in enumerate(HELD_OUT):
        o, d = ngp_rays(held, frame, i)
        img = render_view(ema_model, grid, o, d, bg).reshape(HEIGHT, WIDTH, 3)
        log(f"held-out view {i} (of default_cameras({2 * N_VIEWS}))  model vs scene PSNR "
            f"{psnr(img, held_images[k]):.2f} dB")

    # ---- write the snapshot
    thresh = grid.threshold()
    bits = grid.values > thresh

    def flushed(level: float) -> torch.Tensor | None:
        """The grid with optical thicknesses in [0, level) written as 0, or None if that would change any
        occupancy decision (value > min(0.01, mean), the mean taken after flushing, as a loader sees it)."""
        v = grid.values.clone()
        v[(v >= 0) & (v < level)] = 0.0
        same = bool(torch.equal(bits, v > min(MIN_OPTICAL_THICKNESS, float(v.clamp_min(0).mean()))))
        return v if same else None

    def write(values: torch.Tensor) -> int:
        tree = build_snapshot_tree(
            grid=model.encoding.config, density_params=ema_model.density_mlp.flat_params().numpy(),
            rgb_params=ema_model.rgb_mlp.flat_params().numpy(),
            grid_params=ema_model.encoding.flat_params().numpy(),
            aabb_scale=AABB_SCALE, params_type="__half", scale=frame.scale, offset=frame.offset,
            density_grid=values.reshape(1, GRID_RES, GRID_RES, GRID_RES).numpy(), cameras=ngp_cams,
            background_color=(1.0, 1.0, 1.0, 1.0), write_per_level_scale=False, training_step=step)
        tree["snapshot"]["loss"] = float(np.mean(losses[-50:])) if losses else 0.0
        tree["snapshot"]["nerf"]["rgb"]["rays_per_batch"] = int(rays_per_batch)
        tree["snapshot"]["nerf"]["rgb"]["measured_batch_size"] = int(samples[-1]) if samples else 0
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_snapshot(args.out, tree)
        return args.out.stat().st_size

    # Flushing small optical thicknesses to 0 keeps the gzip small and changes no occupancy decision (each
    # level is checked by flushed()): first only values below 1e-4 (instant-ngp's decayed long tail); if the
    # file is still over the size limit, every value below the occupancy threshold min(0.01, mean) (neither
    # instant-ngp's bitfield nor its mesh-export gating at 0.01 can tell the difference then).
    values = None
    for level in (FLUSH_BELOW, thresh):
        values = flushed(level)
        if values is None:
            log(f"flushing below {level:.3g} would change occupancy; not done")
            continue
        size = write(values)
        log(f"wrote {args.out} ({size:,} bytes = {size / 2**20:.2f} MiB), density-grid values below "
            f"{level:.3g} written as 0 ({float((values > 0).float().mean()):.1%} of cells non-zero, "
            f"threshold {thresh:.4g})")
        if size <= args.max_bytes:
            break
    else:
        log(f"ERROR: {args.out} is larger than {args.max_bytes:,} bytes")
        return 1

    # ---- round trip through the loader
    field = NgpField(read_snapshot(args.out))
    ours = TrainedField(ema_model, values > min(MIN_OPTICAL_THICKNESS, float(values.clamp_min(0).mean())),
                        frame, field.aabb)
    lo, hi = field.aabb[0], field.aabb[1]
    x = lo + torch.rand(20000, 3, generator=gen) * (hi - lo)
    dirs = torch.nn.functional.normalize(torch.randn(20000, 3, generator=gen), dim=-1)
    g_l, g_o = field.geometry(x), ours.geometry(x)
    c_l, c_o = field.radiance(x, dirs), ours.radiance(x, dirs)
    both = (g_l > 0) & (g_o > 0)
    gate_diff = int(((g_l > 0) != (g_o > 0)).sum())
    rel = ((g_l[both] - g_o[both]).abs() / g_o[both]).median() if bool(both.any()) else torch.tensor(0.0)
    log(f"loader round trip at {x.shape[0]} points: occupancy gate differs at {gate_diff}; "
        f"sigma median rel diff "
        f"{float(rel):.2e}; log-sigma max abs diff "
        f"{float((g_l[both].log() - g_o[both].log()).abs().max()) if bool(both.any()) else 0.0:.2e}; "
        f"rgb max abs diff {float((c_l - c_o).abs().max()):.2e}")
    occ = field.occupancy_grid(128)
    for k, i in enumerate(HELD_OUT):
        img_l = VolumeRenderer(field, num_steps=384, occupancy=occ).render(held, i)["rgb"]
        img_o = VolumeRenderer(ours, num_steps=384, occupancy=occ).render(held, i)["rgb"]
        log(f"held-out view {i}: loaded field vs scene {psnr(img_l, held_images[k].numpy()):.2f} dB, "
            f"loaded vs trained model (same renderer) {psnr(img_l, img_o):.2f} dB")
    log(f"total {time.perf_counter() - t_start:.1f}s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
