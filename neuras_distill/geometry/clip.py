"""Cutting a textured mesh at the faces of a box: what a tile keeps of the surface it was trained on.

Owns :func:`clip_mesh_to_box`. A tile of a tiled scene is distilled on its box grown by an overlap margin (its
neighbours' edges are in its training views and its atlas), then cut back to its own box, so neighbouring tiles
meet at the shared plane: every triangle that crosses a cutting plane is split there (Sutherland-Hodgman), the new
vertices on the plane exactly, their uvs interpolated along the edge (linear within a triangle, so the texture
stays where it was). A new vertex is made once per cut edge and shared by the two faces on that edge, so the cut
opens no crack inside the tile. Frames: the box and the vertices share one frame (the bundle's, relative to its
origin).
"""

from __future__ import annotations

import numpy as np

from .mesh import MeshData


def _clip_polygon(poly: list[int], axis: int, bound: float, keep_below: bool, verts: list, uvs: list,
                  cut: dict) -> list[int]:
    """The part of polygon ``poly`` (vertex indices) on the kept side of the plane ``x[axis] = bound``, its new
    vertices appended to ``verts`` / ``uvs`` (float64 lists) once per cut edge (``cut``: (i, j, axis, bound)
    -> index)."""
    def inside(i: int) -> bool:
        x = verts[i][axis]
        return x <= bound if keep_below else x >= bound

    out: list[int] = []
    for k, a in enumerate(poly):
        b = poly[(k + 1) % len(poly)]
        ia, ib = inside(a), inside(b)
        if ia:
            out.append(a)
        if ia != ib:
            key = (min(a, b), max(a, b), axis, bound)
            if key not in cut:
                pa, pb = verts[key[0]], verts[key[1]]
                t = (bound - pa[axis]) / (pb[axis] - pa[axis])
                p = pa + t * (pb - pa)
                p[axis] = bound                                      # exactly on the plane
                ua, ub = uvs[key[0]], uvs[key[1]]
                verts.append(p)
                uvs.append(ua + t * (ub - ua))
                cut[key] = len(verts) - 1
            out.append(cut[key])
    return out


def _clip_faces(faces: np.ndarray, verts: list, uvs: list, planes: list, cut: dict) -> np.ndarray:
    """(F', 3) faces of ``faces`` cut by every plane of ``planes`` ((axis, bound, keep_below)); fans of the
    clipped polygons, the winding kept."""
    if not len(faces):
        return faces.reshape(0, 3)
    v = np.asarray(verts, np.float64)
    keep = np.ones(len(faces), bool)
    straddle = np.zeros(len(faces), bool)
    for axis, bound, below in planes:
        x = v[faces][:, :, axis]
        inside = x <= bound if below else x >= bound
        keep &= inside.any(1)                                      # some corner on the kept side
        straddle |= inside.any(1) & ~inside.all(1)
    whole = faces[keep & ~straddle]
    pieces = []
    for face in faces[keep & straddle]:
        poly = [int(i) for i in face]
        for axis, bound, below in planes:
            poly = _clip_polygon(poly, axis, bound, below, verts, uvs, cut)
            if len(poly) < 3:
                break
        pieces += [[poly[0], poly[k], poly[k + 1]] for k in range(1, len(poly) - 1)]
    return np.concatenate([whole, np.asarray(pieces, np.int64).reshape(-1, 3)]) if pieces else whole


def clip_mesh_to_box(mesh: MeshData, lo, hi, axes=(0, 1)) -> MeshData:
    """``mesh`` (with uvs) cut to the slab ``lo[a] <= x[a] <= hi[a]`` along each of ``axes`` (the ground plane's
    two axes: a tile spans the scene's whole height); vertices no face uses are dropped. Each layer of a
    two-layer mesh is cut on its own (``core_faces`` counts the core's new faces). A bound of +-inf does not cut.
    Returns a new MeshData (float32 vertices as every mesh, the cut vertices exactly on the planes up to that
    rounding); ``stats["clipped_faces"]`` says how many faces were split and dropped."""
    lo, hi = np.asarray(lo, np.float64).reshape(-1), np.asarray(hi, np.float64).reshape(-1)
    planes = [(a, float(lo[a]), False) for a in axes if np.isfinite(lo[a])]
    planes += [(a, float(hi[a]), True) for a in axes if np.isfinite(hi[a])]
    verts = list(np.asarray(mesh.vertices, np.float64))
    uvs = list(np.asarray(mesh.uvs if mesh.uvs is not None else np.zeros((mesh.num_vertices, 2)), np.float64))
    faces = np.asarray(mesh.faces, np.int64)
    layers = [faces] if mesh.core_faces is None else [faces[:mesh.core_faces], faces[mesh.core_faces:]]
    cut: dict = {}
    clipped = [_clip_faces(layer, verts, uvs, planes, cut) for layer in layers]
    joined = np.concatenate(clipped) if clipped else faces
    used, remap = np.unique(joined.reshape(-1), return_inverse=True)
    v, uv = np.asarray(verts, np.float64)[used], np.asarray(uvs, np.float64)[used]
    out = MeshData(v.astype(np.float32), remap.reshape(-1, 3),
                   None if mesh.uvs is None else uv.astype(np.float32),
                   stats=dict(mesh.stats), core_faces=None if mesh.core_faces is None else len(clipped[0]),
                   normal_smoothing=mesh.normal_smoothing)
    out.stats["clipped_faces"] = {"before": int(mesh.num_faces), "after": int(out.num_faces),
                                  "cut_edges": len(cut)}
    return out


__all__ = ["clip_mesh_to_box"]
