"""Probe a field for the numerical breakages of the stability note (docs/stability.md) before distilling it.

This module owns :func:`probe_field`. It samples the field cheaply (a coarse lattice over its aabb, a few
hundred probe rays from its cameras, a few thousand colour samples) and returns a
:class:`~neuras_distill.stability.report.StabilityReport` with one :class:`Item` per probe:

* ``finite.geometry`` / ``finite.colour``: NaN/Inf outputs, their fraction and bounding box;
* ``density.stiffness`` / ``sdf.stiffness``: σ·δ percentiles on occupied cells (density), ``inv_s`` and the
  opacity shell width it implies against the teacher step (SDF), and the step count needed so no surface is
  skipped, measured by compositing the probe rays at 128..1024 steps against 2048 steps with the project's
  own compositing (:mod:`~neuras_distill.render.compositing`);
* ``sdf.eikonal``: |∇f| by central differences near the zero set; ``sdf.sign``: negative inside;
  ``surface.present``: a zero crossing (SDF) or density above the mesh level;
* ``scale.float32``: box size and distance from the origin against float32 resolution;
* ``cameras.inside`` / ``cameras.box``: camera centres inside the geometry, on the box boundary, grazing rays;
* ``colour.range``: radiance outside [0, 1].

Adaptations are recommendations keyed by :class:`~neuras_distill.config.DistillConfig` settings
(``teacher.num_steps``...); the pipeline applies them (see docs/stability.md).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import BadInputError
from ..playback.projection import shift_cameras
from ..render.compositing import alpha_from_sdf, optical_depth, weights_from_alpha
from ..render.local_frame import LocalFrameField, box_centre, far_from_origin, float64_positions
from ..render.rays import ray_aabb
from .report import Item, StabilityReport

if TYPE_CHECKING:
    from ..fields.base import Field

#: Step counts (per aabb diagonal) the probe rays are composited at; the reference is REF_STEPS.
CANDIDATE_STEPS = (128, 256, 512, 1024)
REF_STEPS = 2048
LATTICE = 2 * REF_STEPS           # probe-ray lattice intervals per diagonal (midpoints of REF_STEPS steps)
#: Mean |opacity(steps) - opacity(REF_STEPS)| over the probe rays that counts as "no surface skipped".
OPACITY_TOL = 0.005
#: Density below which a lattice cell counts as empty in the statistics (OccupancyGrid.from_field judges a
#: cell by its optical depth instead: the same at a unit box's default resolution).
OCCUPIED_SIGMA = 0.01
#: Fraction of non-finite geometry (or colour) samples above which a field is refused.
MAX_NONFINITE = 0.05
#: float32 position resolution against the finest length the pipeline resolves (voxel or step).
ULP_FINE, ULP_REFUSE = 1e-3, 0.25
MAX_STEPS = 8192
#: Largest mesh grid the check recommends (512^3 = 1.3e8 field evaluations).
GRID_CAP = 513
#: |grad f| median above which an SDF is reported as not a distance (adapted: the occupancy grid bounds it).
STEEP_GRADIENT = 1.5


def _as_np(t) -> np.ndarray:
    return t.detach().cpu().numpy() if isinstance(t, torch.Tensor) else np.asarray(t)


def _eval(fn, x: np.ndarray, chunk: int, out_dim: int | None = None) -> np.ndarray:
    """fn on float32 points (N, 3) in chunks -> float64 numpy (N,) or (N, out_dim)."""
    outs = []
    with torch.no_grad():
        for i in range(0, x.shape[0], chunk):
            xs = torch.from_numpy(np.ascontiguousarray(x[i:i + chunk], dtype=np.float32))
            y = fn(xs)
            y = _as_np(y).astype(np.float64)
            outs.append(y.reshape(-1) if out_dim is None else y.reshape(-1, out_dim))
    if not outs:
        return np.zeros((0,) if out_dim is None else (0, out_dim))
    return np.concatenate(outs, axis=0)


def _bbox(points: np.ndarray) -> list:
    return [points.min(axis=0).round(6).tolist(), points.max(axis=0).round(6).tolist()] if len(points) else []


def _probe_cameras(field, cameras, n: int, width: int):
    """Up to ``n`` cameras (evenly picked) resized to ``width`` pixels; None when there are none."""
    from ..render.cameras import Cameras

    if cameras is None:
        cameras = getattr(field, "cameras", None)
    if cameras is None:
        make = getattr(field, "default_cameras", None)
        if callable(make):
            try:
                cameras = make(max(n, 2), 64, 64)
            except (TypeError, ValueError, BadInputError):
                cameras = None
    if cameras is None:
        box = torch.as_tensor(field.aabb, dtype=torch.float64).reshape(2, 3)
        centre = 0.5 * (box[0] + box[1])
        radius = 1.5 * float((box[1] - box[0]).norm())
        cameras = Cameras.orbit(centre, radius, n, width=64, height=64, elevation_deg=(10.0, 45.0))
    if not isinstance(cameras, Cameras):
        raise BadInputError(f"cameras must be an nd.Cameras, got {type(cameras).__name__}")
    idx = sorted({int(round(i)) for i in np.linspace(0, len(cameras) - 1, min(n, len(cameras)))})
    picked = cameras[idx]
    return picked.resized(width, max(1, round(picked.height * width / picked.width))), cameras


# ---------------------------------------------------------------------------------------------- probes
class _Ctx:
    """What the probes share: the field, its box, the lattice samples and the probe rays."""

    def __init__(self, field, cameras, num_steps: int, grid_resolution: int, samples: int, rays: int,
                 chunk: int):
        # a box far from the world origin is probed in the frame the run works in (``render.local_frame``)
        self.world_field = field
        self.frame = LocalFrameField(field, box_centre(field.aabb)) if far_from_origin(field.aabb) else None
        field = self.frame if self.frame is not None else field
        self.field, self.kind = field, field.kind
        self.box = _as_np(torch.as_tensor(field.aabb, dtype=torch.float64)).reshape(2, 3).astype(np.float64)
        self.extent = self.box[1] - self.box[0]
        self.diag = float(np.linalg.norm(self.extent))
        self.num_steps, self.grid_resolution, self.chunk = int(num_steps), int(grid_resolution), int(chunk)
        self.step = self.diag / self.num_steps
        self.voxel = float(self.extent.max()) / max(self.grid_resolution - 1, 1)
        self.inv_s = None
        if self.kind == "sdf":
            from ..render.occupancy import default_inv_s
            self.inv_s = float(default_inv_s(field))
        # lattice: cell centres of an r^3 grid (r = samples per axis)
        r = int(samples)
        self.r = r
        self.cell = self.extent / r
        axes = [self.box[0, k] + (np.arange(r) + 0.5) * self.cell[k] for k in range(3)]
        self.points = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        self.values = _eval(field.geometry, self.points, chunk)
        self.finite = np.isfinite(self.values)
        # cameras and probe rays
        side = max(2, int(math.isqrt(max(rays // 8, 4))))
        self.cams, self.all_cams = _probe_cameras(self.world_field, cameras, 8, side)
        if self.frame is not None:
            self.cams, self.all_cams = (shift_cameras(c, self.frame.origin) for c in (self.cams, self.all_cams))
        o, d = [], []
        for i in range(len(self.cams)):
            oi, di = self.cams.rays(i)
            o.append(oi.reshape(-1, 3))
            d.append(di.reshape(-1, 3))
        self.ray_o = torch.cat(o).double().numpy()
        self.ray_d = torch.cat(d).double().numpy()
        self.lattice = _ray_lattice(self)


def _finite_geometry(c: _Ctx) -> Item:
    bad = ~c.finite
    frac = float(bad.mean())
    values = {"nonfinite_fraction": frac, "nan": int(np.isnan(c.values).sum()), "inf": int(np.isinf(c.values).sum()),
              "samples": int(c.values.size)}
    if not bad.any():
        return Item("finite.geometry", "finiteness", values, "fine", "geometry() is finite on the probe lattice")
    values["bbox"] = _bbox(c.points[bad])
    where = f"{frac:.2%} of the probe lattice, box {values['bbox']}"
    what = "SDF" if c.kind == "sdf" else "density"
    if frac > MAX_NONFINITE:
        return Item("finite.geometry", "finiteness", values, "refused",
                    f"the {what} is NaN/Inf at {where} (more than {MAX_NONFINITE:.0%}); fix the checkpoint "
                    "or shrink the aabb to exclude that region")
    how = ("intervals with a NaN/Inf end get opacity 0" if c.kind == "sdf" else "compositing NaN -> 0")
    return Item("finite.geometry", "finiteness", values, "adapted",
                f"NaN/Inf {what} at {where}: treated as empty space ({how}, grid outside value)")


def _surface(c: _Ctx) -> Item:
    v = c.values[c.finite]
    if v.size == 0:
        return Item("surface.present", c.kind, {}, "refused",
                    "the field is NaN/Inf everywhere in its box; check the checkpoint and its aabb")
    if c.kind == "sdf":
        lo, hi = float(v.min()), float(v.max())
        values = {"sdf_min": lo, "sdf_max": hi, "inside_fraction": float((v < 0).mean())}
        ray_neg = c.lattice is not None and bool((np.nan_to_num(c.lattice[1], nan=1.0) < 0).any())
        if lo >= 0 and ray_neg:
            values["found_by"] = "probe rays only"
            return Item("surface.present", "sdf", values, "fine",
                        "zero crossings present along the probe rays (thinner than the probe lattice)")
        if lo >= 0 or hi <= 0:
            what = "no negative values (empty)" if lo >= 0 else "no positive values (everything is inside)"
            return Item("surface.present", "sdf", values, "refused",
                        f"the SDF has no zero crossing in its box: {what}; check the aabb encloses the object "
                        "and is not inside it, and that the field kind is 'sdf'")
        return Item("surface.present", "sdf", values, "fine", "zero crossings present")
    smax = float(v.max())
    level = min(math.log(2.0) / c.voxel, 0.5 * smax) if smax > 0 else 0.0
    values = {"sigma_max": smax, "mesh_level": level, "above_level_fraction": float((v > level).mean()) if smax else 0.0}
    if smax <= 0:
        return Item("surface.present", "density", values, "refused",
                    "the density is zero everywhere in its box (nothing to mesh); check the aabb "
                    "(--foreground-box) and that the field kind is 'density'")
    return Item("surface.present", "density", values, "fine", "density above the mesh level present")


def _ray_lattice(c: _Ctx):
    """Probe rays clipped to the box, sampled at LATTICE intervals per diagonal (endpoints).

    Returns (t (R, M+1), values (R, M+1) with NaN where not sampled, n (R,) lattice intervals per ray, dt (R,)).
    """
    box32 = torch.from_numpy(c.box).float()
    t0, t1, hit = ray_aabb(torch.from_numpy(c.ray_o).float(), torch.from_numpy(c.ray_d).float(), box32)
    hit = hit.numpy()
    o, d = c.ray_o[hit], c.ray_d[hit]
    t0, t1 = t0.numpy()[hit].astype(np.float64), t1.numpy()[hit].astype(np.float64)
    if o.shape[0] == 0:
        return None
    kmax = LATTICE // min(CANDIDATE_STEPS)
    length = t1 - t0
    n = np.maximum(kmax, np.ceil(length / (c.diag / LATTICE) / kmax).astype(np.int64) * kmax)
    m = int(n.max())
    i = np.arange(m + 1)
    valid = i[None, :] <= n[:, None]
    dt = length / n
    t = t0[:, None] + i[None, :] * dt[:, None]
    pts = o[:, None, :] + t[..., None] * d[:, None, :]
    vals = np.full(t.shape, np.nan)
    vals[valid] = _eval(c.field.geometry, pts[valid], c.chunk)
    return t, vals, n, dt, length


def _opacity_at(c: _Ctx, vals: np.ndarray, n: np.ndarray, dt: np.ndarray, k: int) -> np.ndarray:
    """Per-ray opacity with coarse steps of ``k`` lattice intervals, composited with the project's formulas."""
    r, mp1 = vals.shape
    m = (mp1 - 1) // k
    steps = n // k
    j = np.arange(m)
    valid = j[None, :] < steps[:, None]
    if c.kind == "density":
        mid = vals[:, j * k + k // 2]
        sigma = torch.from_numpy(np.where(valid, np.nan_to_num(mid, nan=0.0, posinf=1e30), 0.0)).float()
        tau = optical_depth(sigma, torch.from_numpy(dt * k)[:, None].float())
        return (1.0 - torch.exp(-tau.double().sum(-1))).numpy()
    f = np.nan_to_num(vals, nan=1e3, posinf=1e3, neginf=-1e3)
    prev = torch.from_numpy(f[:, j * k]).float()
    nxt = torch.from_numpy(f[:, np.minimum(j * k + k, mp1 - 1)]).float()
    alpha = alpha_from_sdf(prev, nxt, c.inv_s) * torch.from_numpy(valid).float()
    w, _ = weights_from_alpha(alpha)
    return w.sum(-1).double().numpy()


def _stiffness(c: _Ctx) -> tuple[Item, dict]:
    name = f"{c.kind}.stiffness"
    values: dict = {"teacher_steps": c.num_steps, "step": c.step}
    if c.kind == "density":
        v = np.nan_to_num(c.values, nan=0.0, posinf=0.0)
        occ = v > OCCUPIED_SIGMA
        if occ.any():
            sd = v[occ] * c.step
            values.update(occupied_fraction=float(occ.mean()), sigma_delta_p50=float(np.percentile(sd, 50)),
                          sigma_delta_p99=float(np.percentile(sd, 99)), sigma_delta_max=float(sd.max()))
    else:
        values["inv_s"] = c.inv_s
        values["shell_width"] = 4.4 / c.inv_s          # 10 %..90 % of the logistic CDF
        values["s_times_step"] = c.inv_s * c.step
    lat = c.lattice
    extra = {}
    if lat is None:
        return Item(name, c.kind, values, "fine", "no probe ray crosses the box"), extra
    t, vals, n, dt, length = lat
    ref = _opacity_at(c, vals, n, dt, LATTICE // REF_STEPS)
    errors = {}
    for steps in CANDIDATE_STEPS:
        op = _opacity_at(c, vals, n, dt, LATTICE // steps)
        errors[steps] = float(np.abs(op - ref).mean())
    needed = next((s for s in CANDIDATE_STEPS if errors[s] <= OPACITY_TOL), None)
    values = {"steps_needed": needed if needed is not None else f">{CANDIDATE_STEPS[-1]}", **values}
    values["probe_rays"] = int(len(n))
    values["opacity_error"] = {str(k): round(v, 5) for k, v in errors.items()}
    if c.kind == "density":
        sig = np.nan_to_num(vals, nan=0.0, posinf=1e30)
        runs = _thinnest_run(sig > OCCUPIED_SIGMA, tau=sig * dt[:, None])
        if runs is not None:
            values["thinnest_shell"] = float(runs * float(np.median(dt)))
    extra["grazing"] = float((length < 1e-3 * c.diag).mean())
    if needed is None:
        # not resolved even at 1024 steps: the reference itself may be too coarse; ask for 2x beyond it
        errs_ref = errors[CANDIDATE_STEPS[-1]]
        rec = min(2 * REF_STEPS, MAX_STEPS)
        return Item(name, c.kind, values, "adapted",
                    f"surfaces thinner than a step: at {CANDIDATE_STEPS[-1]} steps the probe rays' opacity still "
                    f"differs by {errs_ref:.3f} from {REF_STEPS} steps; teacher.num_steps raised to {rec}",
                    {"teacher.num_steps": rec}), extra
    if needed > c.num_steps:
        return Item(name, c.kind, values, "adapted",
                    f"stiff: {c.num_steps} steps skip surfaces "
                    f"(opacity error {errors.get(c.num_steps, float('nan')):.3f}"
                    f" > {OPACITY_TOL}); teacher.num_steps raised to {needed}",
                    {"teacher.num_steps": needed}), extra
    return Item(name, c.kind, values, "fine",
                f"{c.num_steps} teacher steps resolve every probed surface (needs {needed})"), extra


def _thin(c: _Ctx) -> Item:
    """Thinnest inside run along the probe rays (SDF < 0, or density above the mesh level; 5th percentile of
    the run lengths) vs the mesh voxel."""
    values = {"mesh_voxel": c.voxel, "grid_resolution": c.grid_resolution}
    if c.lattice is None:
        return Item("geometry.thin", "geometry", values, "fine", "no probe ray crosses the box")
    t, vals, n, dt, length = c.lattice
    tau = None
    if c.kind == "sdf":
        inside = np.nan_to_num(vals, nan=1.0) < 0
    else:
        v = c.values[c.finite]
        vmax = float(v.max()) if v.size else 0.0
        level = min(math.log(2.0) / c.voxel, 0.5 * vmax) if vmax > 0 else math.inf
        sigma = np.nan_to_num(vals, nan=0.0, posinf=1e30)
        inside = sigma > level
        tau = sigma * dt[:, None]
    run = _thinnest_run(inside, tau=tau)
    if run is None:
        return Item("geometry.thin", "geometry", values, "fine", "no probe ray crosses an opaque part")
    thin = float(run * float(np.median(dt)))
    values = {"thinnest": thin, **values}
    if thin >= c.voxel:
        return Item("geometry.thin", "geometry", values, "fine",
                    f"thinnest part along the probe rays {thin:.3g} >= mesh voxel {c.voxel:.3g}")
    # a voxel of at most 2/3 of the thinnest chord puts a lattice point inside it (chords overestimate thickness)
    need = int(math.ceil(1.5 * float(c.extent.max()) / thin / 32.0) * 32) + 1
    cap = GRID_CAP
    if need > cap and c.kind == "density":
        # a lattice misses most of such a part (the level set is a perforated foam): mesh what the training
        # views see instead (their surface depths, fused into a smooth SDF), at the configured grid
        return Item("geometry.thin", "geometry", values, "adapted",
                    f"parts {thin:.3g} thin, below a voxel even at grid {cap} "
                    f"({float(c.extent.max()) / (cap - 1):.3g}): "
                    "geometry.surface set to depths (the mesh is fused from the training views' surface depths; "
                    "a lattice would leave holes)", {"geometry.surface": "depths"})
    if need > cap:
        return Item("geometry.thin", "geometry", values, "adapted",
                    f"parts {thin:.3g} thin, below a voxel even at grid {cap} "
                    f"({float(c.extent.max()) / (cap - 1):.3g}): "
                    f"geometry.grid_resolution raised to {cap}; the mesh may still have holes there",
                    {"geometry.grid_resolution": cap})
    return Item("geometry.thin", "geometry", values, "adapted",
                f"parts {thin:.3g} thin, below the mesh voxel {c.voxel:.3g}: geometry.grid_resolution raised to {need}",
                {"geometry.grid_resolution": need})


def _runs(occ: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of consecutive True along the last axis: (row, start, end) index arrays (end exclusive)."""
    pad = np.zeros((occ.shape[0], 1), dtype=bool)
    x = np.concatenate([pad, occ, pad], axis=1).astype(np.int8)
    dx = np.diff(x, axis=1)
    rows, starts = np.nonzero(dx == 1)
    _, ends = np.nonzero(dx == -1)
    return rows, starts, ends


def _thinnest_run(occ: np.ndarray, percentile: float = 5.0, tau: np.ndarray | None = None) -> float | None:
    """Low percentile (default 5th) of the lengths of runs of consecutive True along the last axis (in samples),
    over all rows: robust to the arbitrarily short chords of rays grazing a silhouette. With ``tau`` (per-sample
    optical depth, same shape) only opaque runs (optical depth >= 1) count: a NeRF's faint noise above the
    mesh level is not a thin part."""
    rows, starts, ends = _runs(occ)
    if rows.size == 0:
        return None
    lengths = ends - starts
    if tau is not None:
        csum = np.concatenate([np.zeros((tau.shape[0], 1)), np.cumsum(tau, axis=1)], axis=1)
        opaque = (csum[rows, ends] - csum[rows, starts]) >= 1.0
        lengths = lengths[opaque]
        if lengths.size == 0:
            return None
    return float(np.percentile(lengths, percentile))


def _eikonal(c: _Ctx) -> Item:
    band = 1.5 * float(np.linalg.norm(c.cell))
    near = c.finite & (np.abs(c.values) < band)
    idx = np.nonzero(near)[0]
    if idx.size == 0:
        return Item("sdf.eikonal", "sdf", {}, "fine", "no lattice point near the zero set")
    rng = np.random.default_rng(0)
    if idx.size > 2048:
        idx = rng.choice(idx, 2048, replace=False)
    p = c.points[idx]
    h = 0.25 * float(c.cell.min())
    offs = np.concatenate([np.eye(3) * h, -np.eye(3) * h])
    vals = _eval(c.field.geometry, (p[:, None, :] + offs[None]).reshape(-1, 3), c.chunk).reshape(-1, 6)
    grad = (vals[:, :3] - vals[:, 3:]) / (2 * h)
    g = np.linalg.norm(grad, axis=1)
    g = g[np.isfinite(g)]
    values = {"grad_p5": float(np.percentile(g, 5)), "grad_p50": float(np.percentile(g, 50)),
              "grad_p95": float(np.percentile(g, 95)), "fd_step": h, "points": int(g.size)}
    med = values["grad_p50"]
    if c.inv_s is not None:
        values["effective_inv_s"] = c.inv_s * med
        values["effective_s_times_step"] = c.inv_s * med * c.step
    if med <= STEEP_GRADIENT:
        note = "unit-gradient SDF" if med >= 0.5 else \
            f"not a distance: the opacity shell is {1 / med:.3g}x as wide as inv_s implies"
        return Item("sdf.eikonal", "sdf", values, "fine", f"|grad f| median {med:.3g} ({note})")
    # the teacher's occupancy grid scales its cell test |f(centre)| < L * half-diagonal + margin by the measured
    # Lipschitz bound L (render/occupancy.py); with L = 1 a steeper SDF lost surface cells
    return Item("sdf.eikonal", "sdf", values, "adapted",
                f"|grad f| median {med:.3g} > {STEEP_GRADIENT}: not a distance; the teacher's empty-space "
                f"skipping widens its cell test by the measured gradient bound (no holes). The opacity shell is "
                f"{med:.3g}x narrower than inv_s implies: dividing geometry() by {med:.3g} and multiplying inv_s "
                "by it gives the same opacities with a true distance")


def _sign(c: _Ctx) -> Item:
    corners = np.array([[c.box[i, 0], c.box[j, 1], c.box[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    fc = _eval(c.field.geometry, corners, c.chunk)
    centres = _as_np(c.all_cams.centers).astype(np.float64)
    fcam = _eval(c.field.geometry, centres, c.chunk)
    values = {"corners_negative": int((fc < 0).sum()), "cameras_negative": int((fcam < 0).sum()),
              "cameras": int(len(fcam))}
    if (fc < 0).mean() > 0.5 and (fcam < 0).mean() > 0.5:
        return Item("sdf.sign", "sdf", values, "refused",
                    f"the SDF is negative outside ({values['corners_negative']}/8 box corners and "
                    f"{values['cameras_negative']}/{len(fcam)} camera centres); it must be negative inside: "
                    "negate geometry() (or set the adapter's sign) and check again")
    return Item("sdf.sign", "sdf", values, "fine", "negative inside, positive at the cameras")


def _cameras(c: _Ctx, grazing: float | None) -> list[Item]:
    centres = _as_np(c.all_cams.centers).astype(np.float64)
    g = _eval(c.field.geometry, centres, c.chunk)
    if c.kind == "sdf":
        inside = g < 0
        rule = "SDF < 0"
    else:
        vmax = float(np.nanmax(np.where(c.finite, c.values, 0.0))) if c.values.size else 0.0
        level = min(math.log(2.0) / c.voxel, 0.5 * vmax) if vmax > 0 else math.inf
        inside = g > level
        rule = f"density > mesh level {level:.3g}"
    ids = np.nonzero(inside)[0].tolist()
    values = {"cameras": int(len(g)), "inside": len(ids), "inside_ids": ids[:10]}
    items = []
    if not ids:
        items.append(Item("cameras.inside", "cameras", values, "fine", f"no camera centre inside ({rule})"))
    elif len(ids) == len(g):
        items.append(Item("cameras.inside", "cameras", values, "refused",
                          f"every camera centre is inside the geometry ({rule}); the views show the inside: "
                          "check the camera file's frame/scale matches the field (or the SDF sign)"))
    else:
        items.append(Item("cameras.inside", "cameras", values, "adapted",
                          f"{len(ids)} of {len(g)} camera centres are inside ({rule}): their views see the inside; "
                          f"drop cameras {ids[:10]} from the camera file"))
    # box boundary and inside the box
    lo, hi = c.box
    tol = 1e-6 * c.diag
    inside_box = np.all((centres >= lo - tol) & (centres <= hi + tol), axis=1)
    dist_face = np.minimum(np.abs(centres - lo), np.abs(centres - hi))
    on_face = inside_box & (dist_face.min(axis=1) <= tol)
    values = {"in_box": int(inside_box.sum()), "on_box_boundary": int(on_face.sum())}
    if grazing is not None:
        values["grazing_ray_fraction"] = grazing
    expl = "cameras outside the box" if not inside_box.any() else \
        f"{int(inside_box.sum())} cameras inside the box (rays start at t = 0, robust slab test)"
    if on_face.any():
        expl += f"; {int(on_face.sum())} exactly on a box face (handled by the parallel-axis slab test)"
    items.append(Item("cameras.box", "cameras", values, "fine", expl))
    return items


def _scale(c: _Ctx) -> Item:
    """float32 positions against the finest length (voxel, teacher step, probe cell). Near the world origin,
    the farthest coordinate of the box and the cameras decides. A box far from it is worked on in a local
    frame around its centre (every float32 stage), so only the field's own arithmetic can lose precision:
    fine when it computes positions in float64 (``local_frame.float64_positions``), else judged at the
    float32 spacing of its world coordinates."""
    centres = _as_np(c.all_cams.centers).astype(np.float64)
    world_box = c.box if c.frame is None else c.box + c.frame.origin
    world_centres = centres if c.frame is None else centres + c.frame.origin
    far = float(max(np.abs(world_box).max(), np.abs(world_centres).max() if centres.size else 0.0))
    ulp = float(np.spacing(np.float32(far)))
    finest = min(c.voxel, c.step, 0.25 * float(c.cell.min()))
    ratio = ulp / finest
    distance = float(np.linalg.norm(world_box.mean(0)))
    values = {"box_size": c.extent.max().item(), "box_centre_distance": distance, "max_abs_coordinate": far,
              "float32_ulp": ulp, "finest_length": finest, "ulp_over_finest": ratio,
              "local_frame": c.frame is not None}
    if c.frame is not None:
        precise = float64_positions(c.world_field)
        values["field_float64_positions"] = precise
        where = (f"the box lies {distance:.3g} units from the origin: every float32 stage works relative to its "
                 "centre")
        if precise:
            return Item("scale.float32", "scale", values, "fine",
                        f"{where}, and the field computes positions in float64")
        messages = (f"{where}; the field rounds positions to float32, {ratio:.2g} of the finest step",
                    f"{where}, but the field rounds positions to float32 there: {ratio:.2g} of a voxel/step; "
                    "compute positions in float64 in the field to remove it",
                    f"{where}, but the field rounds positions to float32 there: {ulp:.2g} apart, {ratio:.2g} of its "
                    f"finest step {finest:.3g}; compute positions in float64 in the field (subtract a float64 centre "
                    "before casting)")
    else:
        messages = (f"float32 resolves positions to {ratio:.2g} of the finest step",
                    f"float32 positions are quantised to {ratio:.2g} of a voxel/step; every float32 stage after "
                    "the teacher works relative to the box's centre",
                    f"the box lies {far:.3g} units from the origin but its finest step is {finest:.3g}: float32 "
                    f"positions are quantised to {ratio:.2g} of a step; recentre the field (subtract a float64 "
                    "centre from positions and cameras) before distilling")
    level = 0 if ratio <= ULP_FINE else 1 if ratio <= ULP_REFUSE else 2
    verdict = ("fine", "adapted", "refused")[level]
    return Item("scale.float32", "scale", values, verdict, messages[level], *(({},) if verdict == "adapted" else ()))


def _colour(c: _Ctx, max_points: int = 4096) -> list[Item]:
    v = np.where(c.finite, c.values, np.nan)
    if c.kind == "sdf":
        sel = np.abs(v) < 2.0 * float(np.linalg.norm(c.cell))
    else:
        sel = v > OCCUPIED_SIGMA
    idx = np.nonzero(np.nan_to_num(sel, nan=0).astype(bool))[0]
    rng = np.random.default_rng(1)
    if idx.size > max_points:
        idx = rng.choice(idx, max_points, replace=False)
    if idx.size == 0:
        return [Item("colour.range", "colour", {"points": 0}, "fine", "no surface point to sample")]
    x = c.points[idx]
    d = rng.normal(size=x.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    outs = []
    with torch.no_grad():
        for i in range(0, len(x), c.chunk):
            outs.append(_as_np(c.field.radiance(torch.from_numpy(x[i:i + c.chunk]).float(),
                                                torch.from_numpy(d[i:i + c.chunk]).float())).astype(np.float64)
                        .reshape(-1, 3))
    rgb = np.concatenate(outs)
    bad = ~np.isfinite(rgb).all(axis=1)
    fin = rgb[~bad]
    out = ((fin < -1e-6) | (fin > 1 + 1e-6)).any(axis=1)
    items = []
    vals = {"points": int(len(rgb)), "nonfinite_fraction": float(bad.mean())}
    if bad.any() and bad.mean() > MAX_NONFINITE:
        vals["bbox"] = _bbox(x[bad])
        items.append(Item("finite.colour", "colour", vals, "refused",
                          f"radiance() returns NaN/Inf at {bad.mean():.2%} of surface samples (box {vals['bbox']}, "
                          f"more than {MAX_NONFINITE:.0%}): fix the checkpoint's colour network"))
    elif bad.any():
        vals["bbox"] = _bbox(x[bad])
        items.append(Item("finite.colour", "colour", vals, "adapted",
                          f"radiance() returns NaN/Inf at {bad.mean():.2%} of surface samples (box {vals['bbox']}): "
                          "the teacher composites them as black (NaN -> 0, +Inf -> 1)"))
    else:
        items.append(Item("finite.colour", "colour", vals, "fine", "radiance() finite at surface samples"))
    vals = {"outside_fraction": float(out.mean()) if out.size else 0.0,
            "min": float(fin.min()) if fin.size else 0.0, "max": float(fin.max()) if fin.size else 0.0}
    if out.any():
        items.append(Item("colour.range", "colour", vals, "adapted",
                          f"{out.mean():.2%} of colours outside [0, 1] (min {vals['min']:.3g}, max {vals['max']:.3g}): "
                          "the teacher clamps the composited colour to [0, 1]"))
    else:
        items.append(Item("colour.range", "colour", vals, "fine", "colours within [0, 1]"))
    return items


def probe_field(field: Field, cameras=None, *, samples: int = 64, rays: int = 512, num_steps: int | None = None,
                grid_resolution: int | None = None, chunk: int = 1 << 16, source: str | None = None
                ) -> StabilityReport:
    """Probe ``field`` (Field protocol) for stiff and extreme cases; cheap (a few seconds).

    Args:
        field: kind ``"sdf"`` or ``"density"``, ``aabb``, ``geometry``, ``radiance``.
        cameras: the cameras it will be distilled with (default: ``field.cameras``, its ``default_cameras``,
            or an orbit around the box).
        samples: lattice points per axis over the aabb (cell centres; ``samples**3`` evaluations).
        rays: probe rays (from up to 8 cameras), composited at 128..1024 steps against 2048.
        num_steps: the teacher's steps per diagonal (default ``TeacherConfig.num_steps``).
        grid_resolution: the mesh grid resolution (default ``GeometryConfig.grid_resolution``).
    Returns:
        StabilityReport; ``report.adaptations`` maps config keys to recommended values.
    Raises:
        BadInputError: not a field.
    """
    from ..config import DistillConfig
    from ..fields.base import check_field

    t_start = time.perf_counter()
    check_field(field, probe=False)
    if samples < 4 or samples > 512:
        raise BadInputError(f"probe samples must be in 4..512 per axis, got {samples}")
    cfg = DistillConfig()
    num_steps = cfg.teacher.num_steps if num_steps is None else int(num_steps)
    grid_resolution = cfg.geometry.grid_resolution if grid_resolution is None else int(grid_resolution)
    c = _Ctx(field, cameras, num_steps, grid_resolution, samples, rays, chunk)
    items = [_finite_geometry(c), _surface(c)]
    items.append(_scale(c))
    grazing = None
    if items[1].verdict != "refused":
        stiff, extra = _stiffness(c)
        items.append(stiff)
        items.append(_thin(c))
        grazing = extra.get("grazing")
        if c.kind == "sdf":
            items += [_eikonal(c), _sign(c)]
        items += _cameras(c, grazing)
        items += _colour(c)
    return StabilityReport(source or type(field).__name__, c.kind, items, time.perf_counter() - t_start,
                           {"samples": samples, "rays": rays, "teacher.num_steps": num_steps,
                            "geometry.grid_resolution": grid_resolution, "reference_steps": REF_STEPS,
                            "opacity_tolerance": OPACITY_TOL})
