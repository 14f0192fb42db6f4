"""The geometry stage: field -> textured-ready mesh (sample -> marching cubes -> clean -> smooth if rough ->
decimate -> cull -> unwrap).

Owns only the order of the steps and the stats they leave in ``MeshData.stats``; each step lives in its own
module (grid, marching, cleanup, visibility, unwrap). Prints nothing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..config import GeometryConfig
from ..errors import BadInputError
from ..logs import logger
from ..render.volume import FRINGE_OPACITY
from .cleanup import clean_mesh, decimate_in_blocks, smooth_rough
from .colour_level import termination_points
from .depth_fusion import fused_depth_sdf
from .marching import folded_fraction, marching_cubes_field
from .mesh import MeshData
from .unwrap import MAX_UNWRAP_FACES, UnwrapFailed, unwrap
from .visibility import cull_unseen_faces, missed_opaque_fraction, seen_surface_points

#: The library's defaults are the configuration's (one place: ``config.py``).
_GEOMETRY = GeometryConfig()
_log = logger("geometry")

if TYPE_CHECKING:
    from ..fields.base import Field

#: A two-layer mesh's shell (``MeshData.core_faces``) gets this share of the face budget (it only draws a
#: soft fringe's fade outside the core's silhouette) ...
SHELL_FACE_FRACTION = 0.2
#: ... and its charts are laid out at this linear scale, i.e. a quarter of the texels per area of the core.
SHELL_TEXEL_SCALE = 0.5


def shell_budget(face_budget: int) -> int:
    """Faces of a two-layer mesh's shell for a total ``face_budget`` (the core gets the rest)."""
    return max(4, int(face_budget * SHELL_FACE_FRACTION))


#: Truncation of the fused depth SDF in voxels: beyond the 4-voxel fringe offsets ``marching.outward_levels``
#: tries, so those levels stay inside the fused values' range.
FUSION_TRUNCATION_VOXELS = 6.0
#: A density field's level set whose mesh misses more than this fraction of the opaque training pixels (teacher
#: opacity >= 0.5, :data:`HOLE_INSET_PX` inside the opaque region, near the mesh's coverage) is perforated: the
#: fused surface depths are meshed as well and the one that misses less is kept. The nerfstudio fixture's level set
#: at ln2 / step missed most of the plate and half the bunny (11.5% holes, 15.4 dB); its fused depths: 0.7% holes,
#: 30.0 dB.
LEVEL_SET_MAX_MISSED = 0.02
#: Pixels inside the opaque region that count for that test (and the stage-by-stage count,
#: ``stats['missed_after_<step>']``): holes, not the silhouette's rim. One pixel, not two: two eroded holes a few
#: pixels wide away (a far floor tile; the nerfstudio 360 fixture's level set missed 1.2% at two pixels and 3.6% at
#: one, and meshed from its fused depths instead it scores 29.16 against 28.61 dB to nerfstudio's renders, 26.99
#: against 25.00 inside the box).
HOLE_INSET_PX = 1
#: Fused surface depths take faint pixels too: a training pixel whose opacity reaches this but not 0.5 votes for a
#: surface at its fringe depth (where its opacity reaches ``render.volume.FRINGE_OPACITY``) instead of free space.
#: A partly trained nerfacto ground is such a haze (opacity 0.1-0.6 from view to view): at 0.5 only its speckles
#: were opaque, and each was a hole in the mesh (orbit360: 2.4% of the opaque training pixels missed, 0.9% held-out
#: holes), seen through to the skyboxes.
FAINT_SURFACE_OPACITY = 0.3
#: A mesh point within this many voxels of the field's surface depth along a training ray is where the views see
#: that surface (``visibility.seen_surface_points``), and a component within it of such points is kept.
SEEN_SURFACE_VOXELS = 2.0
#: A density field's decimated level set whose core has more than this share of adjacent faces folded (normals
#: over 90 degrees apart, ``marching.folded_fraction``) is tangled: the from-ngp ball's colour-level core, inside
#: its noisy fog, came out of decimation with 49% folded (smoothing its positions does not untangle it; xatlas
#: cut it into 6-10 thousand charts, the played surface shows facets). Its fused surface depths: 2.3% folded,
#: 1722 charts, 34.16 -> 35.04 dB, FLIP 0.0285 -> 0.0269 (same teacher). The demo's level set: 0.05%; the NGP
#: bunny's at the end-to-end test's small settings 10%, where its fused depths spread faces over the fog under
#: the base (mesh median height 0.04 instead of the bunny's 0.1-0.6): rough, not tangled.
TANGLED_FOLDED_FRACTION = 0.20


@dataclass
class Surface:
    """The extracted surface before its final unwrap (:func:`extract_surface`).

    Attributes:
        mesh: the cleaned, decimated, culled mesh (world coordinates; one layer, or two with ``core_faces``)
            and the stats of every step so far.
        layout: (V, 3) positions xatlas lays the charts out from (a two-layer mesh's shell shrunk by
            ``SHELL_TEXEL_SCALE``), or None (the vertices).
        trial: ``mesh`` unwrapped at ``trial_resolution`` (the texel-density choice of the atlas side measures
            its UV area; it is the final mesh when that side is chosen).
    """

    mesh: MeshData
    layout: np.ndarray | None
    trial: MeshData
    trial_resolution: int

    def save(self, folder) -> None:
        import json

        self.mesh.save_npz(folder / "surface.npz")
        self.trial.save_npz(folder / "trial.npz")
        if self.layout is not None:
            np.save(folder / "layout.npy", self.layout, allow_pickle=False)
        (folder / "surface.json").write_text(json.dumps(
            {"stats": self.mesh.stats, "trial_stats": self.trial.stats, "trial_resolution": self.trial_resolution},
            default=_json_value))

    @classmethod
    def load(cls, folder) -> "Surface":
        import json

        info = json.loads((folder / "surface.json").read_text())
        mesh, trial = MeshData.load_npz(folder / "surface.npz"), MeshData.load_npz(folder / "trial.npz")
        mesh.stats, trial.stats = info["stats"], info["trial_stats"]
        layout = np.load(folder / "layout.npy", allow_pickle=False) if (folder / "layout.npy").exists() else None
        return cls(mesh, layout, trial, int(info["trial_resolution"]))


def _json_value(o):
    return o.item() if isinstance(o, np.generic) else str(o)


def extract_surface(field: Field, train_cameras, config: GeometryConfig = _GEOMETRY, *, trial_resolution: int = 1024,
                    density_level: float | None = None, max_unwrap_faces: int = MAX_UNWRAP_FACES,
                    field_opacity=None, field_depth=None) -> Surface:
    """Sample, mesh, clean, decimate and cull the surface of ``field``, and unwrap it once at
    ``trial_resolution``; :func:`unwrap_surface` then unwraps it at the atlas side the run chooses.

    Args:
        field: Field (kind, aabb, geometry).
        train_cameras: ``Cameras`` used for visibility culling (ignored when ``config.cull_unseen`` is False).
        config: the geometry section: ``grid_resolution`` (marching-cubes lattice points along the longest box
            side), ``face_budget`` (faces after decimation), ``unwrap_timeout_s`` (per xatlas attempt),
            ``cull_unseen`` and ``cull_margin_deg`` (culling keeps what cameras turned by this angle around the
            training cameras' look-at points see: ``visibility.cull_unseen_faces``), ``core_level``, ``shell``
            and ``surface`` ("depths": mesh the fused depths straight away, for parts thinner than a voxel).
        trial_resolution: side of the square atlas of the trial unwrap.
        density_level: iso-level override for density fields.
        field_opacity: optional (N, H, W) opacity of the field in ``train_cameras``: the iso-level then moves
            outwards until the mesh encloses the field's soft fringe (``marching.marching_cubes_field``).
        field_depth: optional ((N, H, W) surface depths, (N, H, W) fringe depths, (N, H, W) opacities) of the
            field in ``train_cameras`` (``render.volume``): a density field whose level set is foam (a trained
            NeRF's unsupervised interior) that xatlas cannot unwrap (tunnels and pockets: ``unwrap.UnwrapFailed``)
            is then meshed again from the fused surface depths (``depth_fusion.fused_depth_sdf``), its fringe
            shell from the fused fringe depths; ``stats['level_set_unwrap_failure']`` says why. With
            ``field_opacity`` too and ``config.core_level`` "colour", a fringed density field's core sits where
            its training rays terminate (``colour_level``), not at the surface level.

    Returns:
        :class:`Surface`: its mesh has two layers (``core_faces`` set) when ``field_opacity`` made marching cubes
        add a fringe shell (each layer cleaned, decimated and culled on its own, the shell to :func:`shell_budget`
        faces), and ``stats``: ``faces_marching_cubes``, ``faces_after_clean``, ``faces_after_decimation``,
        ``culled_faces``, ``seconds_{marching_cubes,clean,decimate,cull,surface}`` plus each step's own keys.

    Raises:
        BadInputError: no surface in the box, bad budget, cameras seeing nothing, unwrap failure.
    """
    grid_resolution, face_budget, core_level = config.grid_resolution, config.face_budget, config.core_level
    unwrap_timeout_s, cull_unseen, cull_margin_deg = config.unwrap_timeout_s, config.cull_unseen, config.cull_margin_deg
    from_depths, shell = config.surface == "depths", config.shell
    t_start = time.perf_counter()
    fringe_check = None
    if field_opacity is not None:
        def fringe_check(candidate: MeshData) -> float:
            return missed_opaque_fraction(candidate, train_cameras, field_opacity)
    fusion = termination = hole_check = seen_points = None
    if field_depth is not None:
        def hole_check(candidate: MeshData) -> float:
            return missed_opaque_fraction(candidate, train_cameras, field_depth[2], threshold=0.5,
                                          inset=HOLE_INSET_PX)
    if field_depth is not None and getattr(field, "kind", None) == "density":
        surface_depths, fringe_depths, opacities = field_depth

        def seen_points(candidate: MeshData) -> np.ndarray:
            voxel = float(candidate.stats.get("voxel_size", 0.0) or 0.0)
            return seen_surface_points(candidate, train_cameras, surface_depths, opacities,
                                       tolerance=SEEN_SURFACE_VOXELS * voxel)
        if fringe_check is not None and core_level == "colour":
            termination = termination_points(train_cameras, surface_depths, opacities)

        def fusion(spec, fringe: bool = False):
            depths, opaque = (fringe_depths, FRINGE_OPACITY) if fringe else (surface_depths, 0.5)
            return fused_depth_sdf(spec.origin, spec.spacing, spec.shape, train_cameras, depths, opacities,
                                   truncation=FUSION_TRUNCATION_VOXELS * float(spec.spacing.max()), opaque=opaque,
                                   faint=None if fringe else (fringe_depths, FAINT_SURFACE_OPACITY))

    def simplified(depth_fusion) -> Surface:
        """Marching cubes, cleanup, decimation and culling; the trial unwrap is :func:`with_trial`'s."""
        timings: dict = {}
        t = time.perf_counter()
        _log.info(f"    geometry: sampling the field on a {grid_resolution}^3 grid, marching cubes"
                  + (" on the fused depths" if depth_fusion is not None else ""))
        mesh = marching_cubes_field(field, grid_resolution, level=density_level, fringe_check=fringe_check,
                                    depth_fusion=depth_fusion, termination=termination, shell=shell)
        timings["marching_cubes"] = time.perf_counter() - t  # includes grid sampling (and the fusion)
        _log.info(f"    geometry: {mesh.num_faces} faces in {timings['marching_cubes']:.1f} s; cleanup, decimation to "
                  f"{face_budget} faces, culling")
        mesh, layout = _simplify(mesh, train_cameras, timings, face_budget=face_budget, cull_unseen=cull_unseen,
                                 cull_margin_deg=cull_margin_deg, hole_check=hole_check, seen_points=seen_points)
        if depth_fusion is not None and mesh.core_faces is None:
            mesh = outset_fused_surface(mesh)
            if hole_check is not None:
                mesh.stats["missed_after_outset"] = hole_check(mesh)
        return Surface(mesh, layout, mesh, int(trial_resolution))

    def with_trial(surface: Surface) -> Surface:
        _log.info(f"    geometry: UV unwrap of {surface.mesh.num_faces} faces (xatlas, trial side {trial_resolution})")
        surface.trial = unwrap_surface(surface, trial_resolution, unwrap_timeout_s=unwrap_timeout_s,
                                       max_unwrap_faces=max_unwrap_faces)
        return surface

    if from_depths:
        if fusion is None:
            raise BadInputError("geometry.surface = depths needs a density field and the teacher's surface depths; "
                                "use geometry.surface = auto")
        surface = with_trial(simplified(fusion))
        surface.mesh.stats["surface_from_depths"] = True
        surface.mesh.stats["seconds_surface"] = time.perf_counter() - t_start
        return surface
    surface = simplified(None)
    if fusion is not None:       # perforated or tangled level sets: chosen before either is unwrapped
        surface = _level_set_or_fused_depths(surface, simplified, fusion, train_cameras, field_depth[2])
    try:
        surface = with_trial(surface)
    except UnwrapFailed as failure:
        if fusion is None or surface.mesh.stats.get("surface_from_depths"):
            raise
        # the level set is a trained NeRF's noise (tunnels, pockets): mesh what the cameras saw instead
        surface = with_trial(simplified(fusion))
        surface.mesh.stats["level_set_unwrap_failure"] = str(failure)
        surface.trial.stats["level_set_unwrap_failure"] = str(failure)
    surface.mesh.stats["seconds_surface"] = time.perf_counter() - t_start
    return surface


#: A one-layer surface from fused depth maps is moved this many voxels outwards along its vertex normals. A
#: lattice point near a silhouette projects, in the views that see the silhouette, onto a pixel the surface covers
#: only in part, whose opacity stays under 0.5: those views call the point free space, so the fused surface
#: shrinks and its rims miss a pixel. Measured on checker360 (README CPU command, the stored teacher): 0 / 0.5 / 1
#: voxel: held-out holes 0.69 / 0.20 / 0.06%, 25.28 / 26.19 / 25.72 dB against the teacher (inside the box 24.63 /
#: 26.97 / 25.56, the interior 27.07 / 29.04 / 26.98). Taking the fused distance's 0.5-voxel level instead (its
#: values are distances along the rays, longer than across the surface) moved it less: 0.55%, 25.54 dB.
FUSED_OUTSET_VOXELS = 0.5


def outset_fused_surface(mesh: MeshData) -> MeshData:
    """``mesh`` (one layer, world units, ``stats["voxel_size"]``) with every vertex moved
    :data:`FUSED_OUTSET_VOXELS` voxels along its vertex normal (area-weighted, averaged over coincident
    vertices), ``stats["fused_outset"]`` the distance."""
    distance = FUSED_OUTSET_VOXELS * float(mesh.stats.get("voxel_size", 0.0) or 0.0)
    if distance <= 0 or mesh.num_faces == 0:
        return mesh
    moved = (mesh.vertices.astype(np.float64) + distance * mesh.vertex_normals()).astype(mesh.vertices.dtype)
    return MeshData(moved, mesh.faces, mesh.uvs, {**mesh.stats, "fused_outset": distance},
                    core_faces=mesh.core_faces, normal_smoothing=mesh.normal_smoothing)


def core_folded_fraction(mesh: MeshData) -> float:
    """``marching.folded_fraction`` of the mesh's core layer (all of it for one layer)."""
    faces = mesh.faces if mesh.core_faces is None else mesh.faces[:int(mesh.core_faces)]
    return float(folded_fraction(mesh.vertices, faces)) if len(faces) else 0.0


def _level_set_or_fused_depths(surface: Surface, simplified, fusion, cameras, opacities) -> Surface:
    """``surface`` (a density field's simplified level set, not unwrapped yet), or its fused-depth surface
    (``simplified(fusion)``) when the level set is perforated (misses more than :data:`LEVEL_SET_MAX_MISSED` of
    the opaque training pixels) and the fused one misses fewer, or when it is tangled (over
    :data:`TANGLED_FOLDED_FRACTION` of its core's adjacent faces folded) and the fused one is less so without
    missing more than that share of pixels."""
    missed = missed_opaque_fraction(surface.mesh, cameras, opacities, threshold=0.5, inset=HOLE_INSET_PX)
    folded = core_folded_fraction(surface.mesh)
    surface.mesh.stats.update(level_set_missed=missed, level_set_folded=folded)
    perforated, tangled = missed > LEVEL_SET_MAX_MISSED, folded > TANGLED_FOLDED_FRACTION
    if not (perforated or tangled):
        return surface
    fused = simplified(fusion)
    fused_missed = missed_opaque_fraction(fused.mesh, cameras, opacities, threshold=0.5, inset=HOLE_INSET_PX)
    fused_folded = core_folded_fraction(fused.mesh)
    if perforated:
        keep = fused if fused_missed < missed else surface
    else:
        keep = fused if fused_folded < folded and fused_missed <= max(missed, LEVEL_SET_MAX_MISSED) else surface
    keep.mesh.stats.update(level_set_missed=missed, fused_depths_missed=fused_missed, level_set_folded=folded,
                           fused_depths_folded=fused_folded, surface_from_depths=keep is fused,
                           level_set_defect="perforated" if perforated else "tangled")
    return keep


def unwrap_surface(surface: Surface, resolution: int, *, unwrap_timeout_s: float = _GEOMETRY.unwrap_timeout_s,
                   max_unwrap_faces: int = MAX_UNWRAP_FACES, face_weights: np.ndarray | None = None,
                   page_size: int | None = None) -> MeshData:
    """``surface.mesh`` unwrapped for a ``resolution`` x ``resolution`` atlas (``surface.trial`` when that is
    its side and no ``face_weights`` are given: (F,) texel densities the faces want, ``unwrap``; in pages of
    ``page_size`` when ``resolution`` is larger), with the surface's stats and ``faces_final``,
    ``vertices_final``, ``chart_count``, ``seconds_unwrap``."""
    paged = page_size is not None and int(resolution) > int(page_size)
    if (surface.trial is not surface.mesh and int(resolution) == int(surface.trial_resolution)
            and face_weights is None and not paged):
        return surface.trial
    t = time.perf_counter()
    if face_weights is None and surface.trial is not surface.mesh and surface.trial.uvs is not None:
        # the trial's charts packed again at this side: computing charts is nearly all of xatlas's time
        trial = surface.trial
        source = trial_vertex_sources(surface.mesh, trial)
        layout = None if surface.layout is None else np.asarray(surface.layout)[source]
        mesh = unwrap(MeshData(trial.vertices, trial.faces, None, {}, core_faces=trial.core_faces),
                      timeout_s=unwrap_timeout_s, max_faces=max_unwrap_faces, resolution=int(resolution),
                      layout_vertices=layout, charts=trial.uvs, page_size=page_size)
        mesh.stats["uv_charts_from_trial"] = True
    else:
        mesh = unwrap(surface.mesh, timeout_s=unwrap_timeout_s, max_faces=max_unwrap_faces,
                      resolution=int(resolution), layout_vertices=surface.layout, face_weights=face_weights,
                      page_size=page_size)
    stats = {k: v for k, v in surface.mesh.stats.items() if not k.startswith("uv_")}
    mesh.stats = {**stats, **mesh.stats}
    mesh.stats.update(faces_final=mesh.num_faces, vertices_final=mesh.num_vertices,
                      chart_count=mesh.stats.get("uv_charts"), seconds_unwrap=time.perf_counter() - t)
    return mesh


#: Umbrella-operator steps (weight 0.5) smoothing the positions a rough layer's charts are laid out from.
LAYOUT_SMOOTHING_STEPS = 20


def chart_layout(layer: MeshData) -> np.ndarray:
    """(V, 3) positions xatlas makes ``layer``'s charts from: the vertices themselves (the same array), or for a
    rough layer (smoothed after marching cubes: ``stats['smoothing_steps'] > 0``, a trained NeRF's wrinkled
    level set) those vertices smoothed again by :data:`LAYOUT_SMOOTHING_STEPS` umbrella steps. Decimation folds
    such a surface into crumples smaller than a texel, and xatlas then cuts a chart at every fold: the
    from-ngp ball's 21k-face core came out as 10053 charts (2 faces each; 58 s of xatlas, 7.5% of the atlas on
    the surface). Laid out from the smoothed positions: 6256 charts, 18 s, 11.4%. The geometry drawn is not
    moved; stats ``layout_smoothing_steps``."""
    if not int(layer.stats.get("smoothing_steps", 0) or 0) or layer.num_faces == 0:
        return layer.vertices
    from scipy.sparse import coo_matrix

    v = np.asarray(layer.vertices, dtype=np.float64)
    f = np.asarray(layer.faces, dtype=np.int64)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    edges = np.concatenate([edges, edges[:, ::-1]])
    adjacency = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(v), len(v))).tocsr()
    adjacency.data[:] = 1.0                       # shared edges counted once
    degree = np.maximum(np.asarray(adjacency.sum(axis=1)).reshape(-1), 1.0)[:, None]
    for _ in range(LAYOUT_SMOOTHING_STEPS):
        v = v + 0.5 * (adjacency @ v / degree - v)
    layer.stats["layout_smoothing_steps"] = LAYOUT_SMOOTHING_STEPS
    return v


def trial_vertex_sources(mesh: MeshData, unwrapped: MeshData) -> np.ndarray:
    """(V',) int64: the vertex of ``mesh`` each vertex of ``unwrapped`` (``mesh`` unwrapped: the same faces in the
    same order and corner order, vertices split at seams) is a copy of."""
    source = np.zeros(unwrapped.num_vertices, dtype=np.int64)
    source[np.asarray(unwrapped.faces, dtype=np.int64).reshape(-1)] = np.asarray(mesh.faces, dtype=np.int64).reshape(-1)
    return source


def _simplify(mesh: MeshData, train_cameras, timings: dict, *, face_budget: int, cull_unseen: bool,
              cull_margin_deg: float, hole_check=None, seen_points=None) -> tuple[MeshData, np.ndarray | None]:
    """Clean, decimate and cull (each layer on its own) a marching-cubes mesh. Returns the mesh (with the
    steps' stats) and the positions its charts are laid out from (None for one layer).

    ``hole_check`` (mesh -> fraction of the opaque training pixels it misses) measures the core layer after
    marching cubes and after each step: ``stats['missed_after_<step>']`` (marching_cubes, clean, decimate,
    cull), so a hole in the final mesh is traced to the step that made it. ``seen_points`` (mesh -> (M, 3)
    points where the training views see it as the field's surface) keeps the core's small components that the
    views show (``cleanup.clean_mesh``'s ``keep_near``)."""
    n_mc = mesh.num_faces
    missed_after: dict = {}
    if hole_check is not None:
        missed_after["marching_cubes"] = hole_check(mesh.layers()[0])
    layers = mesh.layers()
    budgets = [face_budget] if len(layers) == 1 else [face_budget - shell_budget(face_budget),
                                                      shell_budget(face_budget)]
    done, counts = [], {"clean": 0, "dec": 0, "culled": 0}
    for layer, budget in zip(layers, budgets):
        t = time.perf_counter()
        keep = {}
        if seen_points is not None and not done:
            keep = dict(keep_near=seen_points(layer),
                        keep_radius=SEEN_SURFACE_VOXELS * float(layer.stats.get("voxel_size", 0.0) or 0.0))
        layer = smooth_rough(clean_mesh(layer, **keep))
        timings["clean"] = timings.get("clean", 0.0) + time.perf_counter() - t
        counts["clean"] += layer.num_faces
        core = hole_check is not None and not done
        if core:
            missed_after["clean"] = hole_check(layer)

        t = time.perf_counter()
        layer = decimate_in_blocks(layer, budget)
        timings["decimate"] = timings.get("decimate", 0.0) + time.perf_counter() - t
        counts["dec"] += layer.num_faces
        if core:
            missed_after["decimate"] = hole_check(layer)

        if cull_unseen:           # each layer alone: the shell must not hide the core from the cameras
            t = time.perf_counter()
            layer = cull_unseen_faces(layer, train_cameras, margin_deg=cull_margin_deg)
            timings["cull"] = timings.get("cull", 0.0) + time.perf_counter() - t
            counts["culled"] += int(layer.stats.get("culled_faces", 0))
            if core:
                missed_after["cull"] = hole_check(layer)
        done.append(layer)
    layouts = [chart_layout(layer) for layer in done]
    if len(done) == 1:
        mesh = done[0]
        layout = None if layouts[0] is done[0].vertices else layouts[0]
    else:
        core, shell = done
        stats = dict(core.stats, shell_faces=shell.num_faces,
                     **{f"shell_{k}": v for k, v in shell.stats.items()
                        if k.startswith(("clean_", "decimate_", "cull_", "smooth", "layout_"))
                        and isinstance(v, (int, float))})
        mesh = MeshData.two_layers(core, shell, stats)
        centre = layouts[1].mean(axis=0)
        layout = np.concatenate([layouts[0], centre + SHELL_TEXEL_SCALE * (layouts[1] - centre)])
    mesh.stats.update(faces_marching_cubes=n_mc, faces_after_clean=counts["clean"],
                      faces_after_decimation=counts["dec"], culled_faces=counts["culled"],
                      **{f"missed_after_{k}": v for k, v in missed_after.items()},
                      **{f"seconds_{k}": v for k, v in timings.items()})
    return mesh, layout


__all__ = ["Surface", "extract_surface", "unwrap_surface"]
