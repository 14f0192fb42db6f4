"""UV unwrap with xatlas in a child process with a time limit (the only xatlas importer).

xatlas segfaults or runs for minutes on some meshes (very regular meshes, > ~100k faces; jpcy/xatlas#151), and a
segfault cannot be caught in-process. So :func:`unwrap` runs it in a ``spawn`` child process (no fork of a
process holding torch/OpenMP threads) and waits with a time limit. On a crash or timeout it retries once with a
tiny deterministic vertex jitter (5% of the mean edge length, seed 0; only the positions xatlas sees are
jittered, the returned geometry is exact); when that also fails it raises :class:`BadInputError` asking for a
smaller face budget. Meshes above ``max_faces`` are refused before starting. xatlas sees the mesh centred and
scaled to unit size (:func:`normalized_layout`): its fixed epsilons fail on millimetre meshes otherwise.

UV convention (checked against xatlas's own chart image, xatlas 0.0.11): xatlas's uv (u, v), divided by the
atlas width/height, addresses texel column ``u * W`` and row ``v * H`` of its image whose row 0 is v = 0. That is
exactly :class:`MeshData`'s convention (row 0 of the texture array is v = 0, OpenGL upload order), so no flip
is applied.

Atlas size: with ``PackOptions.resolution = R`` and automatic texels-per-unit, xatlas only approximates R
(measured: a 256 request gave 324 x 304). The distiller uses a square R x R texture, so the uvs are scaled
uniformly by ``R / max(atlas_width, atlas_height)`` into [0, 1]^2 (aspect preserved, texel grid aligned at the
origin). xatlas's padding (requested ``padding`` texels, plus the bilinear margin) shrinks by that factor; when
the effective padding would fall below ``min_padding`` texels, the atlas is generated again with a larger
padding. ``stats['uv_padding_texels']`` records the effective padding at R.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import time
from multiprocessing.connection import wait as mp_wait

import numpy as np

from ..config import MAX_UNWRAP_FACES, GeometryConfig
from ..errors import BadInputError
from .mesh import MeshData, unit_frame

#: Test hook: when this environment variable is "abort" the child calls os.abort() (simulated segfault),
#: "hang" makes it sleep past the time limit. Read in the child only.
CRASH_HOOK_ENV = "NEURAS_DISTILL_TEST_XATLAS_FAULT"
#: Earlier uvs given as ``charts`` (in [0, 1]) reach xatlas in these texel units (it sizes the charts from their
#: layout positions again; the uvs give only each chart's shape).
CHART_UV_TEXELS = 1024.0


class UnwrapFailed(BadInputError):
    """xatlas crashed or timed out twice on a mesh (the message names the face budget to try)."""


# ---------------------------------------------------------------------------------------------- child side
def _xatlas_worker(conn, vertices: np.ndarray, faces: np.ndarray, options: dict) -> None:
    """Runs in the child: unwrap, send back a dict (or nothing when it crashes)."""
    try:
        import resource
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a crash must not write a core file
    except Exception:  # pragma: no cover - non-POSIX
        pass
    fault = os.environ.get(CRASH_HOOK_ENV, "")
    if fault == "abort":
        os.abort()
    if fault == "hang":
        time.sleep(3600)
    import xatlas

    def generate(resolution: int, padding: int, texels_per_unit: float = 0.0):
        atlas = xatlas.Atlas()
        atlas.add_mesh(vertices, faces)
        chart = xatlas.ChartOptions()
        chart.max_iterations = int(options["max_iterations"])
        atlas.generate(chart, _pack_options(resolution, padding, texels_per_unit))
        return atlas

    padding = int(options["padding"])
    resolution = int(options["resolution"])
    weights = options.get("face_weights")
    if weights is not None:    # first the charts, then the same charts packed at their weighted sizes
        vertices, faces, input_uvs, pass1_vmapping = _weighted_charts(generate(resolution, padding), vertices,
                                                                      faces, weights)
        generate = _packer(vertices, faces, input_uvs)
    elif options.get("input_uvs") is not None:     # an earlier unwrap's charts, packed again
        generate = _packer(vertices, faces, options["input_uvs"])
    atlas = generate(resolution, padding)
    if atlas.atlas_count != 1:  # did not fit one page: let xatlas size one atlas freely, scaled later
        atlas = generate(0, padding)
    scale = resolution / max(atlas.width, atlas.height)
    if padding * scale < options["min_padding"]:
        padding = int(math.ceil(options["min_padding"] / scale)) + 1
        atlas = generate(resolution, padding)
        if atlas.atlas_count != 1:
            atlas = generate(0, padding)
    page_size = int(options.get("page_size") or 0)
    vertex_page = None
    if page_size and resolution > page_size:
        # the same texels per unit as one atlas at ``resolution``, packed into pages of page_size
        texels_per_unit = float(atlas.texels_per_unit) * resolution / max(atlas.width, atlas.height)
        padding = max(padding, int(math.ceil(options["min_padding"])))
        atlas = generate(page_size, padding, texels_per_unit)
        vertex_page = np.asarray(atlas.get_mesh_vertex_assignment(0)[0], dtype=np.int64)
    vmapping, indices, uvs = atlas[0]
    if weights is not None:    # pass 2's vertices are pass 1's: map back to the input mesh's
        vmapping = pass1_vmapping[np.asarray(vmapping, dtype=np.int64)]
    conn.send({"vmapping": np.asarray(vmapping, dtype=np.int64), "indices": np.asarray(indices, dtype=np.int64),
               "uvs": np.asarray(uvs, dtype=np.float32), "chart_count": int(atlas.chart_count),
               "width": int(atlas.width), "height": int(atlas.height), "atlas_count": int(atlas.atlas_count),
               "utilization": float(np.mean(atlas.utilization)), "padding": padding, "vertex_page": vertex_page})
    conn.close()


def _pack_options(resolution: int, padding: int, texels_per_unit: float = 0.0):
    """xatlas packing at about ``resolution`` texels with ``padding`` texels between charts, bilinear-safe;
    with ``texels_per_unit`` (> 0) the charts keep that scale and fill as many atlases of exactly
    ``resolution`` as they need (atlas pages)."""
    import xatlas

    pack = xatlas.PackOptions()
    pack.resolution = int(resolution)
    pack.texels_per_unit = float(texels_per_unit)
    pack.padding = int(padding)
    pack.bilinear = True
    pack.blockAlign = True
    return pack


def _weighted_charts(atlas, vertices: np.ndarray, faces: np.ndarray, weights: np.ndarray):
    """Pass 1's charts (``atlas``) scaled by the faces' wanted texel density: each chart's vertices (split at
    seams, so each belongs to one chart) are scaled about the chart's centroid by the square root of its
    area-weighted mean weight over the whole mesh's (clamped to 1/16 .. 16). Returns the scaled layout positions
    (V1, 3) float32, pass 1's faces (F, 3) uint32, its uvs in texel units (V1, 2) float32 and its vertex
    mapping (V1,) int64 into the input vertices."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    vmapping, indices, uvs = atlas[0]
    vmapping, indices = np.asarray(vmapping, dtype=np.int64), np.asarray(indices, dtype=np.int64)
    pos = np.asarray(vertices, dtype=np.float64)[vmapping]
    n = len(vmapping)
    edges = np.concatenate([indices[:, [0, 1]], indices[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, vertex_chart = connected_components(graph, directed=False)
    face_chart = vertex_chart[indices[:, 0]]
    tri = pos[indices]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    w = np.asarray(weights, dtype=np.float64)      # faces are in the input order (xatlas keeps it)
    charts = int(vertex_chart.max()) + 1
    chart_area = np.bincount(face_chart, weights=area, minlength=charts)
    chart_weight = np.bincount(face_chart, weights=area * w, minlength=charts) / np.maximum(chart_area, 1e-30)
    mean = float((area * w).sum() / max(area.sum(), 1e-30))
    factor = np.clip(np.sqrt(chart_weight / max(mean, 1e-30)), 1.0 / 16.0, 16.0)
    centre = np.stack([np.bincount(face_chart, weights=area * tri[:, :, k].mean(axis=1), minlength=charts)
                       for k in range(3)], axis=1) / np.maximum(chart_area, 1e-30)[:, None]
    scaled = centre[vertex_chart] + factor[vertex_chart, None] * (pos - centre[vertex_chart])
    texel_uvs = np.asarray(uvs, dtype=np.float64) * np.array([atlas.width, atlas.height], dtype=np.float64)
    return scaled.astype(np.float32), indices.astype(np.uint32), texel_uvs.astype(np.float32), vmapping


def _packer(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray):
    """``generate(resolution, padding)`` that packs the given charts (``use_input_mesh_uvs``) at the sizes
    their layout positions give."""
    import xatlas

    def generate(resolution: int, padding: int, texels_per_unit: float = 0.0):
        atlas = xatlas.Atlas()
        atlas.add_mesh(vertices, faces, None, uvs)
        chart = xatlas.ChartOptions()
        chart.use_input_mesh_uvs = True
        atlas.generate(chart, _pack_options(resolution, padding, texels_per_unit))
        return atlas

    return generate


# ---------------------------------------------------------------------------------------------- parent side
def _run_in_child(vertices: np.ndarray, faces: np.ndarray, options: dict, timeout_s: float) -> tuple[str, dict | None]:
    """("ok", result) | ("crashed", None) | ("timeout", None)."""
    ctx = mp.get_context("spawn")
    recv_conn, send_conn = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_xatlas_worker, args=(send_conn, vertices, faces, options), daemon=True,
                       name="neuras-xatlas")
    proc.start()
    send_conn.close()
    status, result = "timeout", None
    try:
        ready = mp_wait([recv_conn, proc.sentinel], timeout=timeout_s)
        if recv_conn in ready:
            try:
                status, result = "ok", recv_conn.recv()
            except (EOFError, OSError):
                status = "crashed"
        elif proc.sentinel in ready:
            status = "crashed"
        return status, result
    finally:
        recv_conn.close()
        if status == "ok":
            proc.join(timeout=5.0)  # it exits right after sending
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=2.0)
        if proc.is_alive():  # pragma: no cover
            proc.kill()
            proc.join()


def _jitter(vertices: np.ndarray, faces: np.ndarray, amount: float = 0.05) -> np.ndarray:
    e = vertices[faces[:, [1, 2, 0]]] - vertices[faces]
    mean_edge = float(np.linalg.norm(e, axis=-1).mean()) if faces.shape[0] else 0.0
    rng = np.random.default_rng(0)
    return (vertices + amount * mean_edge * rng.uniform(-1.0, 1.0, vertices.shape)).astype(np.float32)


def _cut_into_tiles(vertices: np.ndarray, faces: np.ndarray, size: float):
    """The mesh with its vertices duplicated where faces of different cubic tiles (side ``size``, by face
    centroid) meet, so no chart can cross a tile border: (V', 3) vertices, (F, 3) uint32 faces (same order) and
    (V',) int64 the original vertex of each."""
    f = np.asarray(faces, dtype=np.int64)
    cell = np.floor(np.asarray(vertices, dtype=np.float64)[f].mean(axis=1) / size).astype(np.int64)
    _, tile = np.unique(cell, axis=0, return_inverse=True)
    keys = f * (int(tile.max()) + 1) + tile.reshape(-1, 1)
    unique, inverse = np.unique(keys.reshape(-1), return_inverse=True)
    original = unique // (int(tile.max()) + 1)
    return (np.asarray(vertices)[original].astype(np.float32), inverse.reshape(-1, 3).astype(np.uint32),
            original.astype(np.int64))


def uv_face_areas(uvs: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) signed uv area per face (positive = counter-clockwise in uv space)."""
    a, b, c = uvs[faces[:, 0]], uvs[faces[:, 1]], uvs[faces[:, 2]]
    ab, ac = b - a, c - a
    return 0.5 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])


#: The library's defaults are the configuration's (one place: ``config.py``).
_GEOMETRY = GeometryConfig()

#: With face weights, the mesh is cut into cubic tiles of 1/WEIGHTED_TILES of its extent before charting: xatlas
#: makes one chart of a planar region whatever its size (its planar charts ignore ``max_chart_area``), and a
#: road would then be one chart from the pixels at the camera's feet to the horizon, sized by one mean weight.
WEIGHTED_TILES = 48



def normalized_layout(positions: np.ndarray) -> np.ndarray:
    """(V, 3) positions in any world units -> (V, 3) float32 positions for xatlas: centred and scaled to unit
    extent when :func:`~.mesh.unit_frame` says so (xatlas tests areas against fixed float32 epsilons: a
    millimetre mesh, face areas near 1e-8, comes back as an empty 0 x 0 atlas; a mesh 1e5 units from the origin
    loses its low bits), as they are otherwise."""
    positions = np.asarray(positions, dtype=np.float64)
    centre, size = unit_frame(positions)
    return np.ascontiguousarray((positions - centre) / size, dtype=np.float32)


def unwrap(mesh: MeshData, *, timeout_s: float = _GEOMETRY.unwrap_timeout_s, max_faces: int = MAX_UNWRAP_FACES,
           resolution: int | None = None,
           padding: int = 3, min_padding: float = 2.0, max_iterations: int = 1,
           layout_vertices: np.ndarray | None = None, face_weights: np.ndarray | None = None,
           charts: np.ndarray | None = None, page_size: int | None = None) -> MeshData:
    """UV-unwrap ``mesh`` into one square atlas, or into pages when ``resolution`` exceeds ``page_size``.

    Args:
        mesh: vertices (V, 3), faces (F, 3) (cleaned and decimated).
        timeout_s: time limit for each xatlas attempt (there are at most two).
        max_faces: larger meshes are refused up front.
        resolution: texture side R the distiller uses (default 1024); uvs are laid out for an R x R atlas.
        padding: texels xatlas leaves between charts (plus its bilinear margin).
        min_padding: smallest acceptable effective padding at R texels (regenerate with more padding below).
        max_iterations: xatlas ChartOptions.max_iterations (small = fast).
        layout_vertices: optional (V, 3) positions xatlas lays the charts out from (default: the vertices);
            charts are sized by their area there, so a part scaled by k gets k^2 of the texels it would get.
            The returned geometry is always ``mesh.vertices``.
        face_weights: optional (F,) positive texel densities the faces want (e.g. training pixels per unit
            area): the charts are made within tiles of 1/:data:`WEIGHTED_TILES` of the extent (so one chart does
            not span near and far), then packed again with each chart scaled by the square root of its mean
            weight relative to the mesh's, so texels follow what the views need instead of 3D area.
        charts: optional (V, 2) uvs of an earlier unwrap of this very mesh (its vertices split at that unwrap's
            seams, so each vertex lies in one chart; any atlas side): its charts are packed again at
            ``resolution`` instead of being computed anew. Computing the charts is nearly all of xatlas's time
            (the demo's 30k faces: 5.2 s; packing them again: 0.06-0.16 s).
        page_size: largest side of one atlas page (None: no limit). When ``resolution`` exceeds it, the charts
            keep the scale of a one-atlas packing at ``resolution`` and are packed into as many square pages of
            ``page_size`` as they need; the pages are stacked along v: a vertex on page p of P has
            ``v = (p + v_page) / P`` (:func:`atlas_shape`; no chart crosses a page).

    Returns:
        MeshData with vertices (V', 3) split along seams (V' >= V), faces (F, 3) in the same order, uvs (V', 2)
        float32 in [0, 1], and stats ``uv_charts``, ``uv_atlas_width``, ``uv_atlas_height``,
        ``uv_utilization``, ``uv_resolution``, ``uv_padding_texels``, ``uv_attempts``, ``uv_seconds``,
        ``uv_pages`` and ``uv_page_size`` (1 and ``resolution`` for one atlas).

    Raises:
        BadInputError: empty mesh, too many faces, or xatlas crashed/timed out twice.
    """
    resolution = 1024 if resolution is None else int(resolution)
    if resolution < 16:
        raise BadInputError(f"texture resolution must be at least 16 texels, got {resolution}")
    n_faces = mesh.num_faces
    if n_faces == 0 or mesh.num_vertices == 0:
        raise BadInputError("cannot UV-unwrap an empty mesh (no faces); the surface extraction produced nothing — "
                            "check the field's aabb and level")
    if n_faces > max_faces:
        raise BadInputError(f"the mesh has {n_faces} faces, more than the UV unwrap handles ({max_faces}); "
                            f"lower --face-budget (e.g. to {min(max_faces, 100_000)})")
    if not np.isfinite(mesh.vertices).all():
        raise BadInputError("the mesh has NaN or Inf vertices; run clean_mesh first")
    t0 = time.perf_counter()
    layout = np.asarray(mesh.vertices if layout_vertices is None else layout_vertices, dtype=np.float64)
    layout = layout.reshape(-1, 3)
    if layout.shape[0] != mesh.num_vertices or not np.isfinite(layout).all():
        raise BadInputError("unwrap: layout_vertices must be finite, one row per mesh vertex")
    vertices = normalized_layout(layout)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.uint32)
    options = {"resolution": resolution, "padding": int(padding), "min_padding": float(min_padding),
               "max_iterations": int(max_iterations), "page_size": int(page_size or 0)}
    if page_size is not None and int(page_size) < 16:
        raise BadInputError(f"an atlas page must be at least 16 texels on a side, got {page_size}")
    if face_weights is not None:
        weights = np.asarray(face_weights, dtype=np.float64).reshape(-1)
        if weights.shape[0] != n_faces or not np.isfinite(weights).all() or (weights <= 0).any():
            raise BadInputError("unwrap: face_weights must be finite and positive, one per face")
        options["face_weights"] = weights
    if charts is not None:
        if face_weights is not None:
            raise BadInputError("unwrap: charts (packing earlier charts again) and face_weights exclude each other")
        given = np.asarray(charts, dtype=np.float64).reshape(-1, 2)
        if given.shape[0] != mesh.num_vertices or not np.isfinite(given).all():
            raise BadInputError("unwrap: charts must be finite uvs, one row per mesh vertex")
        options["input_uvs"] = np.ascontiguousarray(given * CHART_UV_TEXELS, dtype=np.float32)
    tile_map = None
    if face_weights is not None:
        vertices, faces, tile_map = _cut_into_tiles(vertices, faces, 1.0 / WEIGHTED_TILES)
    attempts = []
    result = None
    for positions in (vertices, None):
        if positions is None:
            positions = _jitter(vertices, faces)
        status, result = _run_in_child(positions, faces, options, timeout_s)
        attempts.append(status)
        if status == "ok":
            break
    if result is None:
        what = "crashed" if attempts[-1] == "crashed" else "timed out"
        raise UnwrapFailed(f"UV unwrap {what} on {n_faces} faces (tried twice, the second time with jittered "
                            f"vertices; {timeout_s:g} s limit per try); lower --face-budget "
                            f"(e.g. to {max(1000, n_faces // 2)}) or raise the unwrap time limit")
    vmapping, indices, uv = result["vmapping"], result["indices"], result["uvs"].astype(np.float64)
    if tile_map is not None:
        vmapping = tile_map[vmapping]
    pages, page_side = 1, resolution
    if result.get("vertex_page") is not None:          # pages of exactly page_size, stacked along v
        pages, page_side = int(result["atlas_count"]), int(page_size)
        uv = np.clip(uv, 0.0, 1.0)
        uv[:, 1] = (result["vertex_page"] + uv[:, 1]) / pages
        padding_texels, utilization = float(result["padding"]), float(result["utilization"])
    else:
        scale = 1.0 / max(result["width"], result["height"])
        uv = uv * np.array([result["width"], result["height"]], dtype=np.float64) * scale
        padding_texels = result["padding"] * resolution * scale
        utilization = result["utilization"] * result["width"] * result["height"] * scale * scale
    uv = np.clip(uv, 0.0, 1.0).astype(np.float32)
    stats = dict(mesh.stats)
    stats.update(uv_charts=result["chart_count"], uv_atlas_width=result["width"], uv_atlas_height=result["height"],
                 uv_utilization=utilization, uv_resolution=resolution, uv_padding_texels=padding_texels,
                 uv_attempts=attempts, uv_seconds=time.perf_counter() - t0,
                 uv_view_weighted=face_weights is not None, uv_pages=pages, uv_page_size=page_side)
    return MeshData(mesh.vertices[vmapping], indices, uv, stats, core_faces=mesh.core_faces)


def atlas_shape(stats: dict) -> tuple[int, int, int]:
    """(height, width, pages) of the feature atlas an unwrapped mesh's ``stats`` describe: one square atlas of
    ``uv_resolution``, or ``uv_pages`` pages of ``uv_page_size`` stacked along v (height = pages * side)."""
    pages = int(stats.get("uv_pages") or 1)
    side = int(stats["uv_page_size"]) if pages > 1 else int(stats["uv_resolution"])
    return pages * side, side, pages


__all__ = ["unwrap", "uv_face_areas", "atlas_shape", "UnwrapFailed", "CRASH_HOOK_ENV", "MAX_UNWRAP_FACES"]
