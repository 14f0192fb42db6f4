"""Field -> triangle mesh by marching cubes (scikit-image's, through ``lattice_mc``).

Owns the choice of iso-level, padding, orientation and the index-to-world mapping:

* The field is sampled with :func:`neuras_distill.geometry.grid.sample_grid` (one global lattice, chunked).
  NaN/Inf samples become the "outside" value (large positive SDF / zero density).
* The grid is padded by one voxel of a value far on the "outside" side of the level, so surfaces cut by the
  box are closed (watertight) by a cap lying on the box face, instead of open.
* SDF fields: level 0. Density fields: the adaptive level of :func:`density_level` (override with ``level``),
  meshed in log space (see :func:`marching_cubes_grid`).
* The level is nudged off values that occur exactly in the grid (exact ties give zero-area triangles and
  holes, scikit-image#8116).
* Orientation: faces are counter-clockwise seen from outside (normals towards increasing SDF / decreasing
  density), so the signed volume is positive. scikit-image's ``gradient_direction`` is chosen per field kind
  (measured with scikit-image 0.26: "descent" gives positive volume for an SDF, "ascent" for a density);
  the result is verified with the signed volume and flipped if a future version disagrees.
* Vertices: ``world = origin + index * spacing`` (scikit-image returns index space times ``spacing`` only).
* Enclosed cavities are filled before meshing (:func:`fill_cavities`): a trained NeRF's density is often high
  only in a thin shell at the surface (the inside is never seen, and Instant-NGP's occupancy grid empties it),
  which meshes as two surfaces a voxel apart. Decimation then folds one into the other (measured on the
  Instant-NGP fixture: 38% of adjacent face pairs folded over, 7,500 UV charts for 20k faces). A cavity no
  ray can reach contributes nothing to any render, so filling it changes no image.
* Soft fringes (:func:`outward_levels`, ``fringe_check``): a trained field's surface fades out over a few
  voxels (a NeRF's density ramps up, a NeuS opacity is a sigmoid of the SDF), and the field's renders show
  that fringe as partly opaque pixels around every silhouette. A mesh at the surface level cuts them off:
  94% of a held-out view's squared error sat in a thin band around the silhouette of a soft-fringed ball.
  Given ``fringe_check`` (mesh -> fraction of the field's opaque pixels the mesh misses), the level moves
  outwards step by step (SDF: +0.5 voxel steps up to 4 voxels; density: halvings down to 1/64 of the
  level) until the mesh encloses the fringe; the texture then learns the fringe's colour view-dependently
  (over a constant background, a partly opaque fringe pixel is one colour per view direction).
* Optionally (``termination``, ``geometry.core_level = "colour"``) a fringed density field's core sits where its
  opaque training rays terminate (``colour_level``) instead of at the surface level, and the shell encloses the
  fringe from there: the interior then has no parallax to learn (gradient ball, training views: 45.9 vs 39.7
  dB), but the shell, coarser and faceted, takes over the outer ring of opaque pixels (held-out silhouette
  band -3.6 dB), so it is not the default.
* Roughness is measured (:func:`folded_fraction`: the share of adjacent face pairs whose normals are more than
  90 degrees apart, ``stats['mc_folded_fraction']``); the geometry stage smooths rough meshes
  (``cleanup.smooth_rough``). A trained field's level set is often rough at the voxel scale (hash-grid noise):
  4.4% on the Instant-NGP fixture, ~0 on analytic and NeuS fields.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Sequence

import numpy as np
from scipy import ndimage

from ..errors import BadInputError
from . import blocks
from .colour_level import colour_level
from .grid import field_outside_value, grid_spec, sample_grid
from .lattice_mc import lattice_marching_cubes, nudge_level, signed_volume
from .mesh import MeshData

if TYPE_CHECKING:
    from ..fields.base import Field

#: Default opacity a ray should collect over one voxel-length step of material for the density level.
DENSITY_STEP_ALPHA = 0.5


def density_level(grid: np.ndarray, step: float, alpha: float = DENSITY_STEP_ALPHA) -> float:
    """Iso-level for a density grid: ``min(-ln(1 - alpha) / step, 0.5 * max(grid))``.

    The first term is the density at which one step of length ``step`` (the voxel size by default) becomes
    ``alpha`` opaque (ln 2 / step for alpha 0.5): a ray crossing one voxel of such material is half blocked.
    The cap at half the peak density keeps soft (low-density, blurry) fields meshable: for a VolSDF Laplace
    density ``sigma = Psi_beta(-sdf) / beta`` the half-peak level is exactly the zero level set, and for sharp
    densities (beta < voxel) the first term puts the surface at most ~0.27 voxel outside the zero level set
    (``sdf = beta * ln(step / (2 beta ln 2))``, largest at beta = step / (2e ln 2)).
    """
    peak = float(np.max(grid)) if grid.size else 0.0
    return float(min(-math.log(1.0 - alpha) / step, 0.5 * peak))


def folded_fraction(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Share of interior edges whose two faces' normals are more than 90 degrees apart (0 for a smooth mesh).
    Edges are one int64 key each (``lo * V + hi``) and normals float32: a 6.7M-face city mesh needs about
    0.7 GB of temporaries, not the 1.5 GB of paired index columns."""
    if faces.shape[0] < 2:
        return 0.0
    v = np.asarray(vertices, dtype=np.float32)
    f = np.asarray(faces, dtype=np.int64)
    a = v[f[:, 0]]
    n = np.cross(v[f[:, 1]] - a, v[f[:, 2]] - a)
    del a
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), np.float32(1e-30))
    nxt = np.roll(f, -1, axis=1)
    keys = (np.minimum(f, nxt) * np.int64(v.shape[0]) + np.maximum(f, nxt)).ravel()   # (3F,), face = index // 3
    del nxt
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    del keys
    pair = sorted_keys[1:] == sorted_keys[:-1]
    del sorted_keys
    if not pair.any():
        return 0.0
    first, second = order[:-1][pair] // 3, order[1:][pair] // 3
    cos = np.einsum("ij,ij->i", n[first], n[second])
    return float((cos < 0).mean())


def fill_cavities(values: np.ndarray, level: float, outward: float) -> tuple[np.ndarray, int]:
    """Fill regions on the outside side of ``level`` that are enclosed by inside voxels.

    Args:
        values: (R0, R1, R2) grid; a voxel is inside when ``(values - level) * outward < 0``.
        outward: +1 when values grow outwards (SDF), -1 when they fall outwards (log density).

    Returns:
        (grid with every enclosed outside voxel set to the grid's most-inside value, number of voxels filled).
        Regions touching the grid's border count as the true outside (the grid is padded with outside values
        before meshing), so surfaces cut by the box are unaffected.
    """
    inside = (values - np.float32(level)) * np.float32(outward) < 0
    if not inside.any():
        return values, 0
    enclosed = ndimage.binary_fill_holes(inside) & ~inside
    count = int(enclosed.sum())
    if count == 0:
        return values, 0
    filled = values.copy()
    filled[enclosed] = values.min() if outward > 0 else values.max()
    return filled, count


def marching_cubes_grid(grid: np.ndarray, origin: Sequence[float], spacing: Sequence[float], kind: str,
                        level: float, *, fill: bool = True) -> MeshData:
    """Marching cubes on a sampled grid (R0, R1, R2) -> MeshData in world units (see module docstring).

    ``grid[i, j, k]`` is the field at ``origin + (i, j, k) * spacing``. Density grids are meshed in log space
    (``log(sigma + 1e-3 * level)`` at ``log(1.001 * level)``): the crossing is then exact for exponential
    density tails (VolSDF/Laplace, trunc_exp NeRF densities) instead of biased outwards by linear interpolation
    (measured on a Laplace sphere with beta = 0.2 voxel: +0.41 voxel linear, +0.23 voxel log).
    The padding value is far beyond the level, so surfaces cut by the box are capped on the box face.
    ``fill``: fill enclosed cavities first (:func:`fill_cavities`); ``stats['mc_cavity_voxels']`` counts them.
    """
    lo, hi = float(grid.min()), float(grid.max())
    if not (lo < level < hi):
        what = ("everywhere outside the surface (no negative SDF values)" if kind == "sdf" and lo >= level else
                "everywhere inside the surface (no positive SDF values)" if kind == "sdf" else
                f"below the density level {level:.4g} everywhere (max {hi:.4g})" if hi <= level else
                f"above the density level {level:.4g} everywhere (min {lo:.4g})")
        raise BadInputError(
            f"the field has no surface inside its box: it is {what}. Check that the aabb encloses the object "
            "(and is not entirely inside it), that the field kind ('sdf' or 'density') is right, "
            "or pass an explicit density level.")
    if kind == "density":
        eps = 1e-3 * level
        values = np.log(np.maximum(grid, 0.0) + np.float32(eps)).astype(np.float32)
        mc_level = float(np.log(level + eps))
        outward = -1.0  # outside = lower values
    else:
        values, mc_level, outward = grid, float(level), 1.0
    vlo, vhi = float(values.min()), float(values.max())
    cavity_voxels = 0
    if fill:
        values, cavity_voxels = fill_cavities(values, mc_level, outward)
    mc_level = nudge_level(values, mc_level)
    pad = mc_level + outward * min(1e4 * (vhi - vlo + abs(mc_level) + 1.0), 1e30)
    padded = np.pad(values, 1, mode="constant", constant_values=np.float32(pad))
    spacing = np.asarray(spacing, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64) - spacing
    gradient_direction = "descent" if kind == "sdf" else "ascent"
    try:
        verts, faces = lattice_marching_cubes(padded, mc_level, gradient_direction, spacing=tuple(spacing))
    except (ValueError, RuntimeError) as exc:
        raise BadInputError(f"the field has no surface inside its box at level {level:.4g} ({exc}); check the "
                            "aabb and the field kind, or pass an explicit density level.") from None
    verts = verts.astype(np.float64) + origin
    faces = faces.astype(np.int64)
    if signed_volume(verts, faces) < 0:  # defensive: keep CCW-from-outside whatever the library does
        faces = faces[:, ::-1]
    return MeshData(verts.astype(np.float32), faces.astype(np.int32), None, {"mc_cavity_voxels": cavity_voxels})


#: Fraction of the field's opaque pixels (training views) a mesh may miss and still count as enclosing the
#: fringe (``fringe_check``).
FRINGE_MISS_TOLERANCE = 0.002


def outward_levels(kind: str, level: float, voxel: float) -> list[float]:
    """Iso-levels from ``level`` outwards, tightest first: SDF ``level + k voxel`` for k = 0, 0.5, .., 4;
    density ``level / 2^j`` for j = 0 .. 6 (a density's tail falls about exponentially with distance; lower
    levels mostly grow a trained NeRF's fog)."""
    if kind == "sdf":
        return [level + k * voxel for k in (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)]
    return [level / 2.0 ** j for j in range(7)]


def mesh_handles(mesh: MeshData) -> int:
    """Handles (genus) summed over the connected components: ``C - chi / 2`` with ``chi = V - E + F``."""
    from .cleanup import face_components

    faces = np.asarray(mesh.faces, dtype=np.int64)
    if faces.shape[0] == 0:
        return 0
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    e = len(np.unique(edges[:, 0] * (int(faces.max()) + 1) + edges[:, 1]))
    v = len(np.unique(faces))
    chi = v - e + faces.shape[0]
    components = len(np.unique(face_components(faces, mesh.num_vertices)))
    return int(max(0, round(components - chi / 2)))


def marching_cubes_field(field: Field, resolution: int | Sequence[int], level: float | None = None, *,
                         density_step: float | None = None, chunk_points: int = 1 << 20,
                         fringe_check=None, fringe_tolerance: float = FRINGE_MISS_TOLERANCE,
                         depth_fusion=None, termination=None, shell: str = "offset") -> MeshData:
    """Mesh the surface of ``field`` (Field protocol: kind, aabb, geometry) in world coordinates.

    Args:
        field: SDF (surface at 0, negative inside) or density field.
        resolution: lattice points along the longest box side (cubic voxels), or (R0, R1, R2).
        level: iso-level override. Default: 0 for SDF, :func:`density_level` for density.
        density_step: step length for the density level rule (default: the voxel size).
        chunk_points: points per field evaluation (memory bound).
        fringe_check: optional callable (MeshData) -> fraction of the field's opaque pixels the mesh misses;
            the level then moves outwards (:func:`outward_levels`) until it is at most ``fringe_tolerance``
            (or the last candidate is reached; see :func:`_enclose_fringe`).
        depth_fusion: optional callable (GridSpec, fringe=False) -> ((R0, R1, R2) SDF, stats) fusing the field's
            surface (or, with ``fringe``, fringe) depth maps (``depth_fusion.fused_depth_sdf``); a density field
            is then meshed from the surface fusion instead of its level set (``geometry.extract`` does so when
            the level set cannot be unwrapped), and its fringe shell candidates are the fringe fusion's level 0
            and outward offsets. ``stats['mc_density_handles']`` counts the level set's handles either way.
        termination: optional ((P, 3) points, (P, 3) directions) where the training rays of opaque pixels
            terminate (``colour_level.termination_points``). With ``fringe_check`` on a density field, the core
            then sits at the level the field's colour comes from (``colour_level.colour_level``) when that lies
            inside the surface level, and the shell encloses the fringe from there; kept only when the result
            misses no more opaque pixels than the surface-level route (``stats['mc_colour_level']``). With
            ``depth_fusion`` the core is the fused SDF's colour level instead (:func:`_fused_colour_core`).
        shell: where that colour core's shell candidates come from: "offset" (surfaces at growing distances
            from the core, :func:`offset_grid`: as smooth as the core wherever the field's fringe is noise) or
            "level" (the density's own lower levels, :func:`outward_levels`).

    Returns:
        MeshData (vertices (V, 3) float32 world, faces (F, 3) int32 CCW from outside; two layers, core and
        shell, when ``fringe_check`` chose a shell) with ``stats``: grid
        shape/spacing, ``mc_level``, ``mc_faces``, ``grid_nonfinite``, ``mc_cavity_voxels``,
        ``mc_folded_fraction``, timings; with ``fringe_check`` also ``mc_surface_level`` (the level before
        moving out), ``mc_fringe_offset_voxels`` (SDF) or ``mc_fringe_divisor`` (density) and
        ``mc_fringe_missed`` (the chosen mesh's missed fraction) and ``mc_fringe_missed_at_surface``.

    Raises:
        BadInputError: the field has no surface inside its box at that level.
    """
    kind = getattr(field, "kind", None)
    if kind not in ("sdf", "density"):
        raise BadInputError(f"field kind must be 'sdf' or 'density', got {kind!r}")
    stats: dict = {}
    outside = field_outside_value(kind, field.aabb)
    spec = grid_spec(field.aabb, resolution)
    if kind == "sdf" and fringe_check is None and spec.num_points > blocks.BLOCK_MIN_POINTS:
        return _sdf_in_blocks(field, spec, 0.0 if level is None else float(level), outside, chunk_points)
    grid = sample_grid(field.geometry, field.aabb, resolution, outside=outside, chunk_points=chunk_points,
                       stats=stats)
    if level is None:
        if kind == "sdf":
            level = 0.0
        else:
            step = float(density_step) if density_step is not None else float(spec.spacing.min())
            level = density_level(grid, step)
            stats["mc_level_rule"] = f"min(ln2/step, 0.5*max) with step={step:.6g}"
    t0 = time.perf_counter()
    mesh = marching_cubes_grid(grid, spec.origin, spec.spacing, kind, float(level))
    shell_grid = None
    if kind == "density":
        stats["mc_density_handles"] = mesh_handles(mesh)
        if depth_fusion is not None:
            grid, fused_stats = depth_fusion(spec)
            kind, level = "sdf", 0.0
            if fringe_check is not None:
                shell_grid = depth_fusion(spec, fringe=True)[0]
                if termination is not None:
                    level = _fused_colour_core(grid, spec, termination, stats)
            mesh = marching_cubes_grid(grid, spec.origin, spec.spacing, kind, level)
            stats.update(fused_stats, mc_surface_from="fused depth maps", mc_handles=mesh_handles(mesh))
    if fringe_check is not None:
        core = None
        if kind == "density" and termination is not None and shell_grid is None:
            core = _colour_core(grid, spec, float(level), termination, stats)
        if core is not None:
            trial_stats: dict = {}
            core_surface = marching_cubes_grid(grid, spec.origin, spec.spacing, kind, core)
            if shell == "offset":
                voxel = float(spec.spacing.max())
                core_mesh, shell_level = _enclose_fringe(
                    offset_grid(grid, core, spec.spacing), spec, "sdf", 0.0, core_surface, fringe_check,
                    fringe_tolerance, trial_stats, levels=[k * voxel for k in (0,) + SHELL_OFFSET_VOXELS])
                trial_stats["mc_shell_from"] = "offsets of the core"
            else:
                core_mesh, shell_level = _enclose_fringe(
                    grid, spec, kind, core, core_surface, fringe_check, fringe_tolerance, trial_stats,
                    levels=[core] + outward_levels(kind, float(level), float(spec.spacing.max())))
            if trial_stats["mc_fringe_missed"] > fringe_tolerance:       # compare with the surface-level route
                plain, plain_level = _enclose_fringe(grid, spec, kind, float(level), mesh, fringe_check,
                                                     fringe_tolerance, stats)
                if stats["mc_fringe_missed"] < trial_stats["mc_fringe_missed"]:
                    core_mesh, shell_level, trial_stats = plain, plain_level, {}
                    stats["mc_colour_level_rejected"] = "its shell missed more of the field's opaque pixels"
            stats.update(trial_stats)
            mesh, level = core_mesh, shell_level
        else:
            mesh, level = _enclose_fringe(grid, spec, kind, float(level), mesh, fringe_check, fringe_tolerance,
                                          stats, shell_grid=shell_grid)
    stats.update(mesh.stats, mc_folded_fraction=folded_fraction(mesh.vertices, mesh.faces))
    stats.update(mc_level=float(level), mc_faces=mesh.num_faces, mc_vertices=mesh.num_vertices,
                 mc_seconds=time.perf_counter() - t0, voxel_size=float(spec.spacing.max()))
    mesh.stats = stats
    return mesh


def _sdf_in_blocks(field: Field, spec, level: float, outside: float, chunk_points: int) -> MeshData:
    """:func:`marching_cubes_field` of a large SDF lattice without a fringe shell (``blocks.py``), its stats
    named as the whole-grid path names them."""
    t0 = time.perf_counter()
    device = getattr(field.aabb, "device", "cpu")             # where sample_grid sends the points too
    mesh = blocks.marching_cubes_blocks(field.geometry, spec, level, outside=outside,
                                        block_points=blocks.BLOCK_POINTS, chunk_points=chunk_points, device=device)
    mesh.stats.update(grid_shape=list(spec.shape), grid_spacing=spec.spacing.tolist(),
                      grid_origin=spec.origin.tolist(), mc_folded_fraction=folded_fraction(mesh.vertices, mesh.faces),
                      mc_level=level, mc_faces=mesh.num_faces, mc_vertices=mesh.num_vertices,
                      mc_seconds=time.perf_counter() - t0 - mesh.stats["grid_seconds"],
                      voxel_size=float(spec.spacing.max()))
    return mesh


#: Distances (voxels) from the colour core at which :func:`offset_grid` shells are tried, tightest first.
SHELL_OFFSET_VOXELS = (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 14, 16)


#: Parts of the core region smaller than this fraction of its volume are left out of :func:`offset_grid`.
OFFSET_MIN_PART = 0.01


def offset_grid(grid: np.ndarray, level: float, spacing, smooth_voxels: float = 1.0) -> np.ndarray:
    """(R0, R1, R2) float32 signed distance (world units, negative inside) to the region where the density
    ``grid`` >= ``level`` (its connected parts of at least :data:`OFFSET_MIN_PART` of its volume), from Euclidean
    distance transforms of that mask and its complement (each measured to the nearest voxel centre on the other
    side, so the zero crossing lies between the boundary voxels), Gaussian-smoothed by ``smooth_voxels`` to take the
    voxel staircase out. Its level sets at a distance d are the core pushed out by d and rounded: a shell that
    follows the core's shape, not the field's fog. A trained NeRF's fringe is hash-grid speckle; its own low-density
    level sets were ragged blobs (the Instant-NGP ball's shell: density / 70, 640k faces before decimation) that
    played as pale shards."""
    from scipy import ndimage

    spacing = tuple(float(x) for x in np.asarray(spacing, np.float64).reshape(3))
    inside = np.asarray(grid) >= level
    labels, count = ndimage.label(inside)
    if count > 1:          # specks of the fringe's noise above the core's level would each grow a shell bubble
        sizes = np.bincount(labels.ravel())[1:]
        keep = np.zeros(count + 1, bool)
        keep[1:] = sizes >= OFFSET_MIN_PART * sizes.sum()
        inside = keep[labels]
    outside_dist = ndimage.distance_transform_edt(~inside, sampling=spacing)
    inside_dist = ndimage.distance_transform_edt(inside, sampling=spacing)
    half = 0.5 * max(spacing)
    signed = np.where(inside, half - inside_dist, outside_dist - half).astype(np.float32)
    if smooth_voxels > 0:
        signed = ndimage.gaussian_filter(signed, sigma=[smooth_voxels * max(spacing) / s for s in spacing])
    return signed.astype(np.float32)


#: The colour level must lie at least this factor inside the surface level to make a core of its own.
COLOUR_LEVEL_MIN_RATIO = 1.1


def _colour_core(grid: np.ndarray, spec, level: float, termination, stats: dict) -> float | None:
    """The density level the field's colour comes from (``colour_level.colour_level``), when it lies inside the
    surface ``level`` by at least :data:`COLOUR_LEVEL_MIN_RATIO` and below half the peak density; else None.
    Records ``mc_colour_level`` (the level found), ``mc_colour_level_points`` and ``mc_colour_level_used``."""
    points, dirs = termination
    if len(points) == 0:
        return None
    eps = np.float32(1e-3 * level)
    found = colour_level(np.log(np.maximum(grid, 0.0) + eps), spec.origin, spec.spacing, points, dirs)
    if found is None:
        return None
    core = float(min(math.exp(found["log_level"]), 0.5 * float(grid.max())))
    used = core > COLOUR_LEVEL_MIN_RATIO * level
    stats.update(mc_colour_level=core, mc_colour_level_points=found["points"], mc_colour_level_used=used)
    return core if used else None


def _fused_colour_core(sdf: np.ndarray, spec, termination, stats: dict) -> float:
    """The level of a fused-depth SDF (world units, negative inside) where the field's colour comes from: the
    ``colour_level`` rule of the density path (the tan^2-weighted mean of the SDF at the termination points of
    opaque training rays) on the fused surface. Fusion carves out to the deepest view's 0.5-opacity depth, where
    head-on rays terminate; oblique rays terminate further out in the fringe, and a core inside their
    termination shows them the surface shifted sideways (parallax at the rim). Clamped to
    :data:`FUSED_COLOUR_MAX_VOXELS`; 0 when no termination point lies on the lattice. Records
    ``mc_colour_level`` and ``mc_colour_level_points``.

    Measured on the Instant-NGP ball (same stored teacher, 4.8k steps, held out at 384x216): the level came to
    +0.44 voxel; interior PSNR 35.55 -> 36.16 dB, of it the ring 4-8 pixels inside the silhouette (12% of the
    interior, 46% of its squared error) 29.5 -> 30.6 dB (training views 30.7 -> 31.6); overall 38.44 -> 38.73."""
    points, dirs = termination
    found = colour_level(-sdf, spec.origin, spec.spacing, points, dirs) if len(points) else None
    if found is None:
        return 0.0
    bound = FUSED_COLOUR_MAX_VOXELS * float(spec.spacing.max())
    level = float(np.clip(-found["log_level"], -bound, bound))
    stats.update(mc_colour_level=level, mc_colour_level_points=found["points"], mc_colour_level_used=True)
    return level


#: The fused-depth core moves at most this many voxels from the fused surface (well inside the fusion's
#: truncation, ``extract.FUSION_TRUNCATION_VOXELS``).
FUSED_COLOUR_MAX_VOXELS = 2.0


def _enclose_fringe(grid, spec, kind: str, level: float, mesh: MeshData, check, tolerance: float,
                    stats: dict, shell_grid=None, levels=None) -> tuple[MeshData, float]:
    """The surface mesh, plus as its shell (a two-layer ``MeshData``, see ``MeshData.core_faces``) the tightest
    mesh among :func:`outward_levels` that misses at most ``tolerance`` of the opaque pixels; when none does,
    the least-missing one if it misses at most half of what the surface mesh misses, else no shell (chasing a
    trained NeRF's fog grows the mesh without covering the fringe). Returns (mesh, shell level). Records what
    was tried in ``stats``.

    Two layers, not the shell alone: a single mesh at the shell level put the texture in front of the surface,
    so the interior colour had to be learnt with parallax through the fringe (the gradient ball's interior
    showed a mosaic of patches); the core keeps the surface where it is and the shell only draws outside the
    core's silhouette. ``levels``: the candidates, ``level`` first (default :func:`outward_levels`)."""
    voxel = float(spec.spacing.max())
    levels = outward_levels(kind, level, voxel) if levels is None else levels
    if shell_grid is not None:       # a fused fringe SDF: its own zero level first, then outward offsets
        grid, levels = shell_grid, [level] + outward_levels("sdf", 0.0, voxel)
    best = (check(mesh), 0, mesh)
    missed_at_surface, first = best[0], mesh
    lo, hi = float(grid.min()), float(grid.max())
    for i, candidate in enumerate(levels[1:], start=1):
        if best[0] <= tolerance:
            break
        if not lo < candidate < hi:
            break
        trial = marching_cubes_grid(grid, spec.origin, spec.spacing, "sdf" if shell_grid is not None else kind,
                                    candidate)
        missed = check(trial)
        if missed < best[0]:
            best = (missed, i, trial)
    if best[0] > tolerance and best[0] > 0.5 * missed_at_surface:     # moving out barely helped: keep the surface
        best = (missed_at_surface, 0, first)
    missed, index, shell = best
    mesh = first if index == 0 else MeshData.two_layers(first, shell)
    stats.update(mc_surface_level=level, mc_fringe_missed_at_surface=missed_at_surface, mc_fringe_missed=missed)
    if shell_grid is not None:
        stats.update(mc_fringe_offset_voxels=levels[index] / voxel if index else 0.0,
                     mc_shell_from="fused fringe depth maps" if index else None)
    elif kind == "sdf":
        stats["mc_fringe_offset_voxels"] = (levels[index] - level) / voxel
    else:
        stats["mc_fringe_divisor"] = level / levels[index]
    return mesh, levels[index]


__all__ = ["offset_grid", "marching_cubes_field", "mesh_handles", "outward_levels", "marching_cubes_grid",
           "fill_cavities", "folded_fraction", "density_level"]
