"""Where the soft-silhouette pass (``silhouette.py``) has to run: thin screen-space strips along the mesh's
silhouette and boundary edges, so the pass shades a few thousand pixels instead of the mesh's whole screen box.

The pass writes into the scene it reads, so it runs in two draws over the same tiles: the blend reads the scene
texture and writes a second texture, then a plain copy (``shaders.COPY_FRAGMENT_SHADER``) writes those tiles back.

Why: on llvmpipe the pass over the box cost the demo a third of its frame time at 1920 x 1080 (hard edges
50.7 ms, soft 75.4 ms: 25 ms of pass, 5 ms of full-frame copy), almost all of it on pixels far from any edge.

Which edges: the coverage of a rasterized mesh is the union of its drawn faces' projections, so its border is made
of projected mesh edges that have drawn faces on one side only: **silhouette edges** (the two faces of the edge
face the camera with opposite signs) and **boundary edges** (one face). Edges are matched by vertex *position*
(vertices split along UV seams are welded first), so a seam is not a boundary. An edge with more than two faces,
or next to a face of zero area, is always kept. A pixel the pass changes has covered and uncovered pixel centres
in its 3 x 3 neighbourhood, so the projected border passes within sqrt(2) pixels of its centre: strips of
half-width :data:`BLEND_RADIUS_PX` (2.5 px) around every such edge contain all of them, and the pass gives the same
picture as over the box (tests/test_silhouette_strips.py compares the two).

Owns: :class:`SilhouetteEdges` (edge adjacency, precomputed once per mesh; per frame the edges facing-sign test
and the strip quads). The GLSL of the strip passes (``STRIP_VERTEX_SHADER``, ``COPY_FRAGMENT_SHADER``) is in
``shaders.py``.
Frames: vertices and the eye in the bundle's frame (``BundleRenderer`` shifts cameras by the bundle's origin),
clip space from the renderer's own ``mvp_for`` matrix, strips in NDC.
"""

from __future__ import annotations

import numpy as np

#: Half-width in pixels of the strips the blend pass runs on (>= sqrt(2) plus rasterization slack).
BLEND_RADIUS_PX = 2.5
#: Side in pixels of the screen tiles the strips are made of (see :meth:`SilhouetteEdges.tiles`).
TILE_PX = 8
#: Longest piece an edge is cut into when marking tiles: PIECE_PX / 2 + BLEND_RADIUS_PX must stay below TILE_PX.
PIECE_PX = 10.0
#: Above this many border edges in a view the pass runs over the mesh's screen box instead of tiles (measured on
#: llvmpipe: marking the tiles of the Instant-NGP ball's 21000 wrinkled-core edges took 20 ms, more than the box).
MAX_TILED_EDGES = 6000
#: Clip-space w below which an edge end counts as behind the camera (clipped there).
_MIN_W = 1e-6

def _clip_segments(seg: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """The parts of (K, 2, 2) segments inside the rectangle [x0, x1] x [y0, y1] (Liang-Barsky); segments
    entirely outside are dropped."""
    p, d = seg[:, 0], seg[:, 1] - seg[:, 0]
    t0, t1 = np.zeros(len(seg)), np.ones(len(seg))
    for axis, lo, hi in ((0, x0, x1), (1, y0, y1)):
        with np.errstate(divide="ignore", invalid="ignore"):
            a, b = (lo - p[:, axis]) / d[:, axis], (hi - p[:, axis]) / d[:, axis]
        flat = d[:, axis] == 0
        inside = (p[:, axis] >= lo) & (p[:, axis] <= hi)
        near, far = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(a, b)), \
            np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(a, b))
        t0, t1 = np.maximum(t0, near), np.minimum(t1, far)
    keep = t0 <= t1
    return np.stack([p[keep] + t0[keep, None] * d[keep], p[keep] + t1[keep, None] * d[keep]], axis=1)


def _weld(vertices: np.ndarray) -> np.ndarray:
    """(V,) int64 id per vertex, equal for vertices at bitwise-equal positions (UV-seam copies)."""
    _, ids = np.unique(np.ascontiguousarray(vertices, np.float32), axis=0, return_inverse=True)
    return ids.reshape(-1).astype(np.int64)


class SilhouetteEdges:
    """Edge adjacency of a triangle mesh and the per-frame strips around its silhouette and boundary edges.

    Args:
        vertices: (V, 3) float32, bundle frame; faces: (F, 3) int (every face drawn: both layers).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces, np.int64).reshape(-1, 3)
        self.vertices = v
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])       # CCW normals, unnormalized
        self.normals = n
        self.offsets = np.einsum("ij,ij->i", n, v[f[:, 0]])                  # n . p for any point p of the face
        self.degenerate = np.linalg.norm(n, axis=1) <= 1e-12 * max(1.0, float(np.abs(v).max(initial=0.0))) ** 2
        welded = _weld(v)[f]                                                  # (F, 3)
        ends = np.stack([f, np.roll(f, -1, axis=1)], axis=-1).reshape(-1, 2)  # (3F, 2) original vertex ids
        keys = np.sort(np.stack([welded, np.roll(welded, -1, axis=1)], axis=-1).reshape(-1, 2), axis=1)
        face_of = np.repeat(np.arange(len(f)), 3)
        order = np.lexsort((keys[:, 1], keys[:, 0]))
        keys, ends, face_of = keys[order], ends[order], face_of[order]
        starts = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)])
        counts = np.diff(np.r_[starts, len(keys)])
        self.edge_ends = ends[starts]                                         # (E, 2) vertex ids to draw
        two = counts == 2
        self.pair_edges = np.flatnonzero(two)                                 # manifold edges ...
        self.pair_faces = np.stack([face_of[starts[two]], face_of[starts[two] + 1]], axis=1)   # ... their faces
        self.always = np.flatnonzero(~two)            # boundary (1 face) and non-manifold (3+ faces) edges
        degenerate_edges = self.degenerate[self.pair_faces].any(axis=1)
        self.always = np.union1d(self.always, self.pair_edges[degenerate_edges])
        self.pair_edges, self.pair_faces = self.pair_edges[~degenerate_edges], self.pair_faces[~degenerate_edges]

    @property
    def num_edges(self) -> int:
        return len(self.edge_ends)

    def border_edges(self, eye: np.ndarray) -> np.ndarray:
        """(K,) indices of the edges the coverage border can lie on, seen from ``eye`` (3,) (bundle frame):
        silhouette edges (faces of opposite facing signs) and the always-kept ones."""
        facing = self.normals @ np.asarray(eye, np.float64) - self.offsets > 0.0     # (F,) front-facing
        sides = facing[self.pair_faces]
        return np.concatenate([self.always, self.pair_edges[sides[:, 0] != sides[:, 1]]])

    def project_border(self, eye: np.ndarray, mvp: np.ndarray, width: int, height: int,
                       border: np.ndarray | None = None) -> np.ndarray:
        """(K, 2, 2) float64 window coordinates (pixels, origin bottom-left) of the two ends of every border edge
        (``border``, default :meth:`border_edges` from ``eye``) projected by ``mvp`` (4, 4). Edges with both ends
        behind the camera are dropped; an end behind it is moved along the edge to just in front."""
        ends = self.edge_ends[self.border_edges(eye) if border is None else border]
        a = self.vertices[ends[:, 0]] @ mvp[:3, :3].T + mvp[:3, 3]            # (K, 4) clip space (rows 0-2 ...
        b = self.vertices[ends[:, 1]] @ mvp[:3, :3].T + mvp[:3, 3]
        a = np.concatenate([a, (self.vertices[ends[:, 0]] @ mvp[3, :3] + mvp[3, 3])[:, None]], axis=1)  # ... + w)
        b = np.concatenate([b, (self.vertices[ends[:, 1]] @ mvp[3, :3] + mvp[3, 3])[:, None]], axis=1)
        keep = (a[:, 3] > _MIN_W) | (b[:, 3] > _MIN_W)
        a, b = a[keep], b[keep]
        for p, q in ((a, b), (b, a)):                                         # clip an end behind the camera
            behind = p[:, 3] <= _MIN_W
            if behind.any():
                t = (2 * _MIN_W - p[behind, 3]) / (q[behind, 3] - p[behind, 3])
                p[behind] = p[behind] + t[:, None] * (q[behind] - p[behind])
        size = np.array([0.5 * width, 0.5 * height])
        return np.stack([(a[:, :2] / a[:, 3:4] + 1.0) * size, (b[:, :2] / b[:, 3:4] + 1.0) * size], axis=1)

    def tiles(self, eye: np.ndarray, mvp: np.ndarray, width: int, height: int,
              border: np.ndarray | None = None) -> np.ndarray:
        """(TH, TW) bool mask of the TILE_PX-square screen tiles (row 0 = bottom) the pass runs on: a superset
        of the tiles with a pixel centre within :data:`BLEND_RADIUS_PX` of a border edge's projection.

        Each projected edge (clipped to the window grown by a tile) is cut into pieces of at most
        :data:`PIECE_PX`; any pixel within the radius of a piece is less than PIECE_PX / 2 + radius < TILE_PX
        from the piece's midpoint, so it lies in the tile of that midpoint or one of its 8 neighbours: the mask
        is the midpoints' tiles grown by one tile."""
        tw, th = -(-int(width) // TILE_PX), -(-int(height) // TILE_PX)
        grid = np.zeros((th + 2, tw + 2), bool)                     # one tile of margin on every side
        seg = _clip_segments(self.project_border(eye, mvp, width, height, border), -TILE_PX, -TILE_PX,
                             width + TILE_PX, height + TILE_PX)
        if len(seg):
            pieces = np.maximum(1, np.ceil(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1) / PIECE_PX)).astype(np.int64)
            owner = np.repeat(np.arange(len(seg)), pieces)
            k = np.arange(len(owner)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
            frac = ((k + 0.5) / pieces[owner])[:, None]
            points = seg[owner, 0] + frac * (seg[owner, 1] - seg[owner, 0])
            cell = np.floor(points / TILE_PX).astype(np.int64) + 1
            cell = np.clip(cell, 0, [tw + 1, th + 1])
            grid[cell[:, 1], cell[:, 0]] = True
        rows = grid.copy()
        rows[1:] |= grid[:-1]
        rows[:-1] |= grid[1:]
        grown = rows.copy()
        grown[:, 1:] |= rows[:, :-1]
        grown[:, :-1] |= rows[:, 1:]
        return grown[1:-1, 1:-1]

    def pass_quads(self, eye: np.ndarray, mvp: np.ndarray, width: int, height: int, box) -> np.ndarray:
        """(6R, 2) float32 NDC triangles the pass runs on for this view: the tiles along the border edges
        (:meth:`tiles`, :meth:`tile_quads`), or the rectangle ``box`` (x, y, w, h window pixels: the mesh's screen
        box, ``projection.screen_box``) when more than :data:`MAX_TILED_EDGES` edges are on the border (a
        wrinkled surface: marking their tiles would cost more than the pass over the box saves)."""
        border = self.border_edges(eye)
        if len(border) > MAX_TILED_EDGES:
            return self.rect_quads(*box, width, height)
        return self.tile_quads(self.tiles(eye, mvp, width, height, border), width, height)

    @staticmethod
    def rect_quads(x: int, y: int, w: int, h: int, width: int, height: int) -> np.ndarray:
        """(6, 2) float32: two NDC triangles covering the window rectangle (x, y, w, h); (0, 2) when it is empty."""
        if w <= 0 or h <= 0:
            return np.zeros((0, 2), np.float32)
        x0, x1 = 2.0 * x / width - 1.0, 2.0 * (x + w) / width - 1.0
        y0, y1 = 2.0 * y / height - 1.0, 2.0 * (y + h) / height - 1.0
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y0], [x1, y1], [x0, y1]], np.float32)

    @staticmethod
    def tile_quads(mask: np.ndarray, width: int, height: int) -> np.ndarray:
        """(6R, 2) float32 NDC corners of two triangles per run of marked tiles in a row of ``mask`` (TH, TW),
        clamped to the ``width`` x ``height`` window: axis-aligned, tile-aligned and never overlapping (on
        llvmpipe, thin overlapping strips cost ten times the pixels they cover)."""
        padded = np.pad(mask, ((0, 0), (1, 1)))
        change = np.diff(padded.astype(np.int8), axis=1)
        rows, starts = np.nonzero(change == 1)
        _, stops = np.nonzero(change == -1)                  # row-major order: the same rows, paired in order
        x0 = starts * TILE_PX / (0.5 * width) - 1.0
        x1 = np.minimum(stops * TILE_PX, width) / (0.5 * width) - 1.0
        y0 = rows * TILE_PX / (0.5 * height) - 1.0
        y1 = np.minimum((rows + 1) * TILE_PX, height) / (0.5 * height) - 1.0
        quads = np.stack([np.stack([x0, y0], 1), np.stack([x1, y0], 1), np.stack([x1, y1], 1),
                          np.stack([x0, y0], 1), np.stack([x1, y1], 1), np.stack([x0, y1], 1)], axis=1)
        return np.ascontiguousarray(quads.reshape(-1, 2), np.float32)


__all__ = ["SilhouetteEdges", "BLEND_RADIUS_PX", "TILE_PX",
           "MAX_TILED_EDGES"]
