"""Mesh cleanup and quadric decimation to a face budget (the only pymeshlab importer).

* :func:`clean_mesh`: drops faces touching non-finite vertices and faces with repeated indices (numpy, before
  pymeshlab: a NaN vertex survives pymeshlab's filters), then in pymeshlab removes duplicate vertices, duplicate
  faces, zero-area faces, unreferenced vertices and repairs non-manifold edges/vertices; finally drops
  connected components with fewer faces than ``min_component_fraction`` of the largest (marching-cubes floaters;
  they also stop decimation from reaching its budget since a closed component cannot shrink below 4 faces).
  A mesh whose float32 positions are too coarse for its edges (far from the origin for its size,
  :data:`MAX_ULP_PER_EDGE`) is refused: its vertices have already collapsed onto each other.
* :func:`decimate`: pymeshlab quadric edge collapse with ``preserveboundary``, ``preservetopology``,
  ``planarquadric`` (keeps flat regions flat; its weight shrinks with the squared edge length for meshes
  finer than :data:`PLANAR_REF_EDGES` edges across, :func:`planar_weight`) and ``optimalplacement`` chosen per
  mesh: on, unless the mesh is thin (smallest box side < 1% of the largest), where it makes spikes and breaks
  watertightness; a pass that produces spikes (vertices leaving the input's box) or opens a closed mesh is
  redone with it off. When a pass overshoots the budget, further passes aim lower (at most ``max_passes``).

* :func:`smooth_rough`: Taubin smoothing (lambda/mu, volume preserving: no shrinking, nothing erased) of a
  mesh whose marching-cubes surface was rough (``mc_folded_fraction`` above :data:`ROUGH_FOLDED_FRACTION`).
  Rough voxel-scale bumps survive quadric decimation as folds that split xatlas charts: on the Instant-NGP
  fixture (4.4% folded) 30 steps took the unwrap from 7,500 to 3,300 charts (with cavities filled). Blurring
  the density grid instead was tried and dropped: in log space it erased the fixture's thin, weakly dense base
  at a 64 grid (-6 dB), in linear space it dilated dense parts by voxels.

All keep the orientation (faces CCW seen from outside) and return a new :class:`MeshData` with stats.
"""

from __future__ import annotations

import time

import numpy as np
import pymeshlab
from scipy import sparse
from scipy.sparse import csgraph

from ..errors import BadInputError
from .mesh import MeshData, unit_frame


# ---------------------------------------------------------------------------------------------- helpers
def _to_meshset(vertices: np.ndarray, faces: np.ndarray) -> "pymeshlab.MeshSet":
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.ascontiguousarray(vertices, dtype=np.float64),
                               face_matrix=np.ascontiguousarray(faces, dtype=np.int32)))
    return ms


def _from_meshset(ms: "pymeshlab.MeshSet") -> tuple[np.ndarray, np.ndarray]:
    m = ms.current_mesh()
    return (np.asarray(m.vertex_matrix(), dtype=np.float64).reshape(-1, 3),
            np.asarray(m.face_matrix(), dtype=np.int64).reshape(-1, 3))


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices and renumber faces."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces]


def face_components(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """(F,) component label per face; faces sharing a vertex are connected.

    The graph is the vertices' (two edges per face join its three corners; labels are those of each face's
    first vertex): 2F entries, where the face-vertex bipartite graph it replaced held 6F in a matrix of F + V
    rows built through a COO copy (a transient that would set the cleanup's peak on large meshes)."""
    f = faces.shape[0]
    if f == 0:
        return np.zeros(0, dtype=np.int64)
    index = np.int32 if num_vertices < 2 ** 31 else np.int64
    rows = np.concatenate([faces[:, 0], faces[:, 1]]).astype(index, copy=False)
    cols = np.concatenate([faces[:, 1], faces[:, 2]]).astype(index, copy=False)
    graph = sparse.csr_matrix((np.ones(2 * f, dtype=np.int8), (rows, cols)), shape=(num_vertices, num_vertices))
    del rows, cols
    _, labels = csgraph.connected_components(graph, directed=False)
    return labels[faces[:, 0]].astype(np.int64, copy=False)


def is_watertight(faces: np.ndarray) -> bool:
    """Every undirected edge is used by exactly two faces."""
    if faces.shape[0] == 0:
        return False
    e = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return bool((counts == 2).all())


def _require_mesh(mesh: MeshData, what: str) -> None:
    if mesh.num_faces == 0 or mesh.num_vertices == 0:
        raise BadInputError(f"cannot {what} an empty mesh (no faces); the surface extraction produced nothing — "
                            "check the field's aabb and level")


# ---------------------------------------------------------------------------------------------- cleanup
#: The largest float32 spacing at a mesh's farthest coordinate, as a fraction of its median edge, that cleanup
#: accepts. Spheres meshed at grids 48-160 and moved away from the origin stayed watertight through cleanup up to
#: 0.020 and lost it from 0.034 (its degenerate faces are removed and coincident vertices merged); at 1e5 (0.0078
#: against edges of 0.008) cleanup dropped 16,576 of 70,892 faces and the decimated radius was 0.0195 off
#: against 0.0014 at the origin.
MAX_ULP_PER_EDGE = 0.025


def _require_resolved(v: np.ndarray, f: np.ndarray) -> None:
    """BadInputError unless float32 positions resolve the edges of the mesh (V, 3) float64 / (F, 3)."""
    far = float(np.abs(v).max())
    ulp = float(np.spacing(np.float32(far)))
    f = f[::max(1, len(f) // 1_000_000)]                # a million faces tell the median edge
    edges = np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1)
    edges = edges[edges > 0]
    if edges.size == 0:
        return
    edge = float(np.median(edges))
    if ulp > MAX_ULP_PER_EDGE * edge:
        raise BadInputError(f"cannot clean a mesh {far:.3g} from the origin: float32 positions there are {ulp:.2g} "
                            f"apart, {ulp / edge:.2g} of its median edge ({edge:.2g}; at most {MAX_ULP_PER_EDGE}), "
                            "so its vertices have collapsed onto each other; recentre it (subtract a float64 "
                            "centre) first")


#: A small component is kept when at least this many of the points the views see as the field's surface
#: (``keep_near``) lie on it.
MIN_SEEN_POINTS = 2


def clean_mesh(mesh: MeshData, *, min_component_fraction: float = 0.005, keep_near: np.ndarray | None = None,
               keep_radius: float = 0.0) -> MeshData:
    """Return a cleaned copy of ``mesh`` (see module docstring).

    Args:
        mesh: vertices (V, 3), faces (F, 3).
        min_component_fraction: components with fewer faces than this fraction of the largest component are
            dropped (0 keeps all) ...
        keep_near: ... unless at least :data:`MIN_SEEN_POINTS` of these (M, 3) points (where the training views
            see the field's surface on this mesh: ``visibility.seen_surface_points``) lie within ``keep_radius``
            of one of their vertices: a piece the views show is a surface, however small (the dark tiles of a
            partly trained field's checkered floor came out of depth fusion as islands of a few hundred faces).

    Returns:
        MeshData with ``stats`` = input stats plus ``clean_faces_in``, ``clean_faces_out``,
        ``clean_components_removed``, ``clean_seconds``.

    Raises:
        BadInputError: no valid face; float32 positions too coarse for the mesh's edges (:data:`MAX_ULP_PER_EDGE`).
    """
    _require_mesh(mesh, "clean")
    t0 = time.perf_counter()
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces.astype(np.int64)
    if f.min() < 0 or f.max() >= len(v):
        raise BadInputError(f"mesh faces reference vertex indices outside [0, {len(v)})")
    finite = np.isfinite(v).all(axis=1)
    keep = finite[f].all(axis=1)
    keep &= (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
    f = f[keep]
    if f.shape[0] == 0:
        raise BadInputError("the mesh has no valid faces (all degenerate or with NaN vertices)")
    v, f = _compact(v, f)
    _require_resolved(v, f)
    ms = _to_meshset(v, f)
    ms.meshing_remove_duplicate_vertices()
    ms.meshing_remove_duplicate_faces()
    ms.meshing_remove_null_faces()
    ms.meshing_remove_unreferenced_vertices()
    ms.meshing_repair_non_manifold_edges(method="Remove Faces")
    ms.meshing_repair_non_manifold_vertices()
    ms.meshing_remove_unreferenced_vertices()
    v, f = _from_meshset(ms)
    del ms                                 # MeshLab's copy (870 MB at 6.7 M faces) before the components
    removed = kept_seen = 0
    if min_component_fraction > 0 and f.shape[0] > 0:
        labels = face_components(f, len(v))
        sizes = np.bincount(labels)
        big = sizes >= min_component_fraction * sizes.max()
        if keep_near is not None and len(keep_near) and not big.all():
            big |= _seen_components(v, f, labels, keep_near, keep_radius)
            kept_seen = int(big.sum() - (sizes >= min_component_fraction * sizes.max()).sum())
        removed = int((~big[np.unique(labels)]).sum())
        if removed:
            f = f[big[labels]]
            v, f = _compact(v, f)
    stats = dict(mesh.stats)
    stats.update(clean_faces_in=mesh.num_faces, clean_faces_out=int(f.shape[0]),
                 clean_components_removed=removed, clean_seconds=time.perf_counter() - t0)
    if keep_near is not None:
        stats["clean_components_kept_seen"] = kept_seen
    return MeshData(v.astype(np.float32), f.astype(np.int32), None, stats)


def _seen_components(v: np.ndarray, f: np.ndarray, labels: np.ndarray, points: np.ndarray,
                     radius: float) -> np.ndarray:
    """(C,) bool: components (``labels`` (F,) of faces ``f`` over vertices ``v``) with at least
    :data:`MIN_SEEN_POINTS` of ``points`` (M, 3) within ``radius`` of one of their vertices."""
    from scipy.spatial import cKDTree

    vertex_label = np.full(len(v), -1, dtype=np.int64)
    vertex_label[f.reshape(-1)] = np.repeat(labels, 3)
    dist, nearest = cKDTree(v).query(np.asarray(points, dtype=np.float64), distance_upper_bound=max(radius, 1e-12))
    owner = vertex_label[nearest[np.isfinite(dist)]]
    counts = np.bincount(owner[owner >= 0], minlength=int(labels.max()) + 1)
    return counts >= MIN_SEEN_POINTS


# ---------------------------------------------------------------------------------------------- smoothing
#: Share of folded adjacent face pairs above which a marching-cubes surface counts as rough.
ROUGH_FOLDED_FRACTION = 0.01


def smooth_rough(mesh: MeshData, *, steps: int = 30, threshold: float = ROUGH_FOLDED_FRACTION) -> MeshData:
    """Taubin-smooth ``mesh`` when ``mesh.stats['mc_folded_fraction']`` exceeds ``threshold``.

    Returns:
        MeshData (same faces, moved vertices) with stats ``smoothing_steps`` (0 when left as is).
    """
    _require_mesh(mesh, "smooth")
    stats = dict(mesh.stats)
    if float(stats.get("mc_folded_fraction", 0.0) or 0.0) <= threshold or steps <= 0:
        stats["smoothing_steps"] = 0
        return MeshData(mesh.vertices, mesh.faces, mesh.uvs, stats)
    ms = _to_meshset(mesh.vertices, mesh.faces)
    ms.apply_coord_taubin_smoothing(stepsmoothnum=int(steps))
    v, f = _from_meshset(ms)
    if f.shape != mesh.faces.shape or not np.isfinite(v).all():   # pymeshlab keeps topology; be sure
        stats["smoothing_steps"] = 0
        return MeshData(mesh.vertices, mesh.faces, mesh.uvs, stats)
    stats["smoothing_steps"] = int(steps)
    return MeshData(v.astype(np.float32), mesh.faces, mesh.uvs, stats)


# ---------------------------------------------------------------------------------------------- decimation
def _check_budget(face_budget) -> int:
    if isinstance(face_budget, bool) or not isinstance(face_budget, (int, np.integer)) or face_budget < 4:
        raise BadInputError(f"face budget must be at least 4 (an integer number of triangles), got {face_budget!r}; "
                            "typical budgets are 20000-200000")
    return int(face_budget)


#: pymeshlab's weight of the planar quadric (its default), kept for meshes with edges at least
#: 1 / :data:`PLANAR_REF_EDGES` of the frame's size long.
PLANAR_WEIGHT = 1e-3
#: Edges across the (unit) frame up to which :data:`PLANAR_WEIGHT` applies as it is. The planar quadric's pull
#: does not shrink with the faces as the geometric quadric's does: on the 1.2 km city (marching-cubes edges
#: 1/1872 of the frame) at 1e-3 it flattened cars, trees, curbs and roof edges, 19.3% of held-out pixels then
#: saw the wrong surface against 4.6% for the undecimated mesh; the same weight with the mesh scaled 10x, or a
#: weight of 3e-5, gave 4.6-4.9%. Every other preset keeps 1e-3 (the street's marching-cubes edges
#: are 1/373 of its box, the quality preset's 1/298; the city's get 4.6e-5).
PLANAR_REF_EDGES = 400.0


def planar_weight(v: np.ndarray, f: np.ndarray) -> float:
    """Planar-quadric weight for the mesh (V, 3) / (F, 3) in the frame it is collapsed in:
    :data:`PLANAR_WEIGHT` scaled by the squared ratio of its median edge to 1 / :data:`PLANAR_REF_EDGES` of
    the frame's size (largest box side), at most 1."""
    size = float((v.max(axis=0) - v.min(axis=0)).max()) if len(v) else 0.0
    if size <= 0.0 or len(f) == 0:
        return PLANAR_WEIGHT
    edge = float(np.median(np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1))) / size
    return PLANAR_WEIGHT * min(1.0, (edge * PLANAR_REF_EDGES) ** 2)


def _quadric_pass(v: np.ndarray, f: np.ndarray, target: int, optimal: bool, preserve_boundary: bool,
                  preserve_topology: bool, planar: bool,
                  weight: float = PLANAR_WEIGHT) -> tuple[np.ndarray, np.ndarray]:
    ms = _to_meshset(v, f)
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(target), qualitythr=0.3, preserveboundary=preserve_boundary, boundaryweight=1.0,
        preservenormal=True, preservetopology=preserve_topology, optimalplacement=optimal,
        planarquadric=planar, planarweight=float(weight), autoclean=True)
    ms.meshing_remove_unreferenced_vertices()
    return _from_meshset(ms)


def _optimal_placement(extent: np.ndarray) -> bool:
    """The automatic ``optimalplacement`` rule: on, unless the mesh's box (3,) ``extent`` is thin (smallest side
    under 1% of the largest), where it makes spikes."""
    return bool(extent.min() >= 0.01 * extent.max())


def _looks_broken(v_in: np.ndarray, f_in_watertight: bool, v: np.ndarray, f: np.ndarray) -> bool:
    lo, hi = v_in.min(axis=0), v_in.max(axis=0)
    margin = 0.01 * float(np.linalg.norm(hi - lo))
    spikes = bool(((v < lo - margin) | (v > hi + margin)).any()) or not np.isfinite(v).all()
    return spikes or (f_in_watertight and not is_watertight(f))


def decimate(mesh: MeshData, face_budget: int, *, preserve_boundary: bool = True, preserve_topology: bool = True,
             optimal_placement: bool | None = None, planar_quadric: bool = True, max_passes: int = 3,
             frame: tuple[np.ndarray, float] | None = None, weight: float | None = None) -> MeshData:
    """Quadric edge collapse down to at most ``face_budget`` faces.

    Args:
        mesh: cleaned mesh (run :func:`clean_mesh` first: floaters cannot be decimated away).
        face_budget: int >= 4.
        optimal_placement: None = automatic (see module docstring).
        frame, weight: the collapse frame (``mesh.unit_frame``) and planar weight (:func:`planar_weight`);
            None: this mesh's own (a block of a larger mesh gets the whole mesh's, :func:`decimate_in_blocks`).

    Returns:
        MeshData with stats ``decimate_faces_in``, ``decimate_faces_out``, ``decimate_passes``,
        ``decimate_optimal_placement``, ``decimate_planar_weight``, ``decimate_budget_reached``,
        ``decimate_seconds``. If topology preservation stops above the budget after ``max_passes`` passes,
        ``decimate_budget_reached`` is False.

    Raises:
        BadInputError: budget < 4 or not an int; empty mesh.
    """
    budget = _check_budget(face_budget)
    _require_mesh(mesh, "decimate")
    t0 = time.perf_counter()
    v0 = mesh.vertices.astype(np.float64)
    f0 = mesh.faces.astype(np.int64)
    stats = dict(mesh.stats)
    if f0.shape[0] <= budget:
        stats.update(decimate_faces_in=int(f0.shape[0]), decimate_faces_out=int(f0.shape[0]), decimate_passes=0,
                     decimate_optimal_placement=None, decimate_budget_reached=True,
                     decimate_seconds=time.perf_counter() - t0)
        return MeshData(mesh.vertices.copy(), mesh.faces.copy(), None, stats)
    # pymeshlab's quadric collapse has fixed epsilons: meshes far from unit size are collapsed at unit size
    centre, size = unit_frame(v0) if frame is None else frame
    v0 = (v0 - centre) / size
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    extent = hi - lo
    auto = optimal_placement is None
    optimal = _optimal_placement(extent) if auto else bool(optimal_placement)
    watertight = is_watertight(f0)
    weight = planar_weight(v0, f0) if weight is None else float(weight)
    v, f = v0, f0
    passes = 0
    target = budget
    while passes < max(1, int(max_passes)):
        nv, nf = _quadric_pass(v, f, target, optimal, preserve_boundary, preserve_topology, planar_quadric,
                                       weight)
        passes += 1
        if optimal and auto and _looks_broken(v0, watertight, nv, nf):
            optimal = False
            nv, nf = _quadric_pass(v, f, target, optimal, preserve_boundary, preserve_topology, planar_quadric,
                                       weight)
        progressed = nf.shape[0] < f.shape[0]
        v, f = nv, nf
        if f.shape[0] <= budget or not progressed:
            break
        # overshoot: aim lower, proportionally to how far off the last pass ended
        target = max(4, int(budget * budget / f.shape[0]))
    stats.update(decimate_faces_in=int(f0.shape[0]), decimate_faces_out=int(f.shape[0]), decimate_passes=passes,
                 decimate_optimal_placement=optimal, decimate_planar_weight=weight,
                 decimate_budget_reached=bool(f.shape[0] <= budget),
                 decimate_seconds=time.perf_counter() - t0)
    return MeshData((v * size + centre).astype(np.float32), f.astype(np.int32), None, stats)


#: Meshes with more faces than this are decimated in blocks (:func:`decimate_in_blocks`).
DECIMATE_BLOCK_MIN_FACES = 2_000_000
#: Faces per block (about 1 GB of pymeshlab's and the watertightness check's temporaries each).
DECIMATE_BLOCK_FACES = 1_500_000


def decimate_in_blocks(mesh: MeshData, face_budget: int, *, min_faces: int = DECIMATE_BLOCK_MIN_FACES,
                       block_faces: int = DECIMATE_BLOCK_FACES) -> MeshData:
    """:func:`decimate` of a large mesh one block at a time, so its memory is a block's, not the whole mesh's.

    The faces are cut into slabs of about ``block_faces`` along the mesh's longest box side (by centroid,
    equal face counts). Each slab is decimated on its own to twice its share of the budget with its cut edges
    kept (``preserve_boundary``: the slabs still meet vertex for vertex) and the whole mesh's frame, planar
    weight and placement rule; the slabs are joined, their shared cut vertices welded (bit-identical
    positions), and the joined mesh, now a few times the budget, is decimated as a whole to the budget, which
    also collapses the dense seams along the cuts. A mesh of at most ``min_faces`` faces goes to
    :func:`decimate` directly. Stats as :func:`decimate`'s, plus ``decimate_blocks``."""
    budget = _check_budget(face_budget)
    _require_mesh(mesh, "decimate")
    faces_in = mesh.num_faces
    if faces_in <= max(int(min_faces), 2 * budget):
        return decimate(mesh, budget)
    t0 = time.perf_counter()
    v_all = mesh.vertices
    centre, size = unit_frame(v_all)
    extent = v_all.max(axis=0) - v_all.min(axis=0)
    axis = int(np.argmax(extent))
    optimal = _optimal_placement(extent)
    weight = planar_weight((v_all.astype(np.float64) - centre) / size, mesh.faces)
    blocks = int(np.ceil(faces_in / max(1, int(block_faces))))
    centroid = v_all[mesh.faces, axis].mean(axis=1)                           # (F,) along the cut axis
    order = np.argsort(centroid, kind="stable")
    del centroid
    parts_v, parts_f, offset = [], [], 0
    for chunk in np.array_split(order, blocks):
        sub_v, sub_f = _compact(v_all, mesh.faces[np.sort(chunk)])
        share = max(4, int(np.ceil(2 * budget * len(chunk) / faces_in)))
        part = decimate(MeshData(sub_v, sub_f, None, {}), share, preserve_boundary=True,
                        optimal_placement=optimal, frame=(centre, size), weight=weight)
        parts_v.append(part.vertices)
        parts_f.append(part.faces.astype(np.int64) + offset)
        offset += part.num_vertices
    del order
    joined_v, inverse = np.unique(np.concatenate(parts_v), axis=0, return_inverse=True)
    joined_f = inverse.reshape(-1)[np.concatenate(parts_f)].astype(np.int32)
    joined = MeshData(joined_v.astype(np.float32), joined_f, None, dict(mesh.stats))
    out = decimate(joined, budget, optimal_placement=optimal, weight=weight)
    out.stats.update(decimate_faces_in=int(faces_in), decimate_blocks=blocks,
                     decimate_faces_joined=int(joined.num_faces), decimate_seconds=time.perf_counter() - t0)
    return out


__all__ = ["clean_mesh", "decimate", "decimate_in_blocks", "smooth_rough", "ROUGH_FOLDED_FRACTION", "face_components",
           "is_watertight"]
