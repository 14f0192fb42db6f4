"""``MeshData``: the triangle mesh passed between geometry, G-buffer, bake and playback stages."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class MeshData:
    """A triangle mesh in world units.

    Attributes:
        vertices: (V, 3) float32 world positions.
        faces: (F, 3) int32 vertex indices, counter-clockwise seen from outside.
        uvs: (V, 2) float32 texture coordinates in [0, 1] (u right, v up, OpenGL convention; texel (i, j) of a
            W x H atlas has its centre at ((i + 0.5) / W, (j + 0.5) / H) with row j = 0 at v = 0), or None
            before unwrapping. After unwrapping vertices are split along seams, so V grows.
        stats: what each processing step did (counts, timings), for the report.
        core_faces: two-layer meshes (a soft fringe's shell around the opaque surface): faces[:core_faces] are
            the core, faces[core_faces:] the shell; a pixel shows the nearest core fragment when a core face
            covers it, else the nearest shell fragment. None: one layer.
        normal_smoothing: rounds of one-ring averaging applied to :meth:`vertex_normals` (0: the plain
            area-weighted normals). The shading normals of a mesh whose shader takes the facing cosine (a fringe
            shell's fade follows the surface's large-scale orientation, not the facets of a bumpy surface).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    stats: dict = field(default_factory=dict)
    core_faces: int | None = None
    normal_smoothing: int = 0

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int32).reshape(-1, 3)
        if self.uvs is not None:
            self.uvs = np.ascontiguousarray(self.uvs, dtype=np.float32).reshape(-1, 2)

    @property
    def num_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    def face_normals(self) -> np.ndarray:
        """(F, 3) float32 unit face normals (right-handed winding: outwards for CCW-from-outside faces; zero
        for degenerate faces), computed in float64 from the vertices."""
        tri = self.vertices[self.faces].astype(np.float64)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 0, n / np.maximum(length, 1e-300), 0.0).astype(np.float32)

    def vertex_normals(self) -> np.ndarray:
        """(V, 3) float32 unit vertex normals: the area-weighted sum of the normals of the faces around each
        vertex *position* (vertices a UV seam duplicates share one normal, so shading is continuous across
        charts), computed in float64; zero where every face around is degenerate. With ``normal_smoothing`` k,
        then k rounds of replacing each position's unit normal by the normalised sum of the unit normals of
        the faces' corners around it (its one ring, itself included). Frame: the vertices'."""
        v = self.vertices.astype(np.float64)
        if not self.num_faces:
            return np.zeros((self.num_vertices, 3), np.float32)
        tri = v[self.faces]
        area_normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])      # length = 2 x area
        _, position = np.unique(self.vertices, axis=0, return_inverse=True)
        position = position.reshape(-1)
        summed = np.zeros((int(position.max()) + 1, 3))
        for corner in range(3):
            np.add.at(summed, position[self.faces[:, corner]], area_normal)
        if self.normal_smoothing > 0:
            summed = _smoothed_normals(summed, position[self.faces], int(self.normal_smoothing))
        n = summed[position]
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 0, n / np.maximum(length, 1e-300), 0.0).astype(np.float32)

    def normal_roughness_deg(self, rounds: int) -> float:
        """Median angle in degrees between the plain vertex normals and the normals after ``rounds`` of smoothing
        (:meth:`vertex_normals`): how far the facets of this surface turn from its larger-scale orientation
        (0 without faces or rounds)."""
        if not self.num_faces or rounds <= 0:
            return 0.0
        plain = MeshData(self.vertices, self.faces).vertex_normals().astype(np.float64)
        smooth = MeshData(self.vertices, self.faces, normal_smoothing=int(rounds)).vertex_normals().astype(np.float64)
        cos = np.clip((plain * smooth).sum(axis=1), -1.0, 1.0)
        return float(np.degrees(np.median(np.arccos(cos))))

    def uv_area(self) -> float:
        """Fraction of the unit uv square the faces cover (sum of |uv triangle areas|, float64; 0 without uvs):
        times an atlas's texel count, the number of texels its training has to fill."""
        if self.uvs is None or not self.num_faces:
            return 0.0
        t = self.uvs.astype(np.float64)[self.faces]
        area = 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                            - (t[:, 1, 1] - t[:, 0, 1]) * (t[:, 2, 0] - t[:, 0, 0]))
        return float(area.sum())

    def layers(self) -> list["MeshData"]:
        """[the mesh] for one layer; [core, shell] (each with only its own vertices, ``stats`` shared) for two."""
        if self.core_faces is None:
            return [self]
        out = []
        for faces in (self.faces[:self.core_faces], self.faces[self.core_faces:]):
            used = np.unique(faces)
            remap = np.full(self.num_vertices, -1, dtype=np.int64)
            remap[used] = np.arange(used.size)
            out.append(MeshData(self.vertices[used], remap[faces], None if self.uvs is None else self.uvs[used],
                                dict(self.stats), normal_smoothing=self.normal_smoothing))
        return out

    @classmethod
    def two_layers(cls, core: "MeshData", shell: "MeshData", stats: dict | None = None) -> "MeshData":
        """One mesh holding ``core`` then ``shell`` (``core_faces`` = core's face count); uvs are kept only
        when both have them."""
        uvs = (np.concatenate([core.uvs, shell.uvs]) if core.uvs is not None and shell.uvs is not None else None)
        return cls(np.concatenate([core.vertices, shell.vertices]),
                   np.concatenate([core.faces, shell.faces + core.num_vertices]), uvs,
                   dict(core.stats if stats is None else stats), core_faces=core.num_faces)

    def __repr__(self) -> str:
        uv = "none" if self.uvs is None else f"{self.uvs.shape} {self.uvs.dtype}"
        layers = "" if self.core_faces is None else f", core_faces={self.core_faces}"
        layers += f", normal_smoothing={self.normal_smoothing}" if self.normal_smoothing else ""
        return (f"MeshData(vertices={self.vertices.shape} {self.vertices.dtype}, "
                f"faces={self.faces.shape} {self.faces.dtype}, uvs={uv}{layers})")

    def save_npz(self, path) -> None:
        arrays = {"vertices": self.vertices, "faces": self.faces}
        if self.uvs is not None:
            arrays["uvs"] = self.uvs
        if self.core_faces is not None:
            arrays["core_faces"] = np.asarray(self.core_faces, dtype=np.int64)
        if self.normal_smoothing:
            arrays["normal_smoothing"] = np.asarray(self.normal_smoothing, dtype=np.int64)
        np.savez_compressed(path, **arrays)

    @classmethod
    def load_npz(cls, path) -> "MeshData":
        with np.load(path, allow_pickle=False) as data:
            return cls(data["vertices"], data["faces"], data["uvs"] if "uvs" in data else None,
                       core_faces=int(data["core_faces"]) if "core_faces" in data else None,
                       normal_smoothing=int(data["normal_smoothing"]) if "normal_smoothing" in data else 0)


def _smoothed_normals(summed: np.ndarray, corners: np.ndarray, rounds: int) -> np.ndarray:
    """(P, 3) per-position normal sums -> unit normals after ``rounds`` of one-ring averaging over the faces'
    ``corners`` (F, 3) position indices (:meth:`MeshData.vertex_normals`); a position without a normal of its own
    takes its ring's."""
    unit = summed / np.maximum(np.linalg.norm(summed, axis=1, keepdims=True), 1e-300)
    for _ in range(rounds):
        around = unit[corners].sum(axis=1)                    # (F, 3): each face's corners' normals
        acc = np.zeros_like(unit)
        for corner in range(3):
            np.add.at(acc, corners[:, corner], around)
        unit = acc / np.maximum(np.linalg.norm(acc, axis=1, keepdims=True), 1e-300)
    return unit


#: Mesh extents (world units) that pymeshlab's quadric collapse and xatlas handle as they are. Both test lengths
#: and areas against fixed epsilons (and keep float32 positions): outside this range, or far from the origin for
#: its size, a mesh is processed centred and scaled to unit size.
SCALE_FREE_RANGE = (0.05, 50.0)


def unit_frame(positions: np.ndarray) -> tuple[np.ndarray, float]:
    """(V, 3) positions -> (centre (3,) float64, size) such that ``(positions - centre) / size`` is what the
    mesh libraries should see: the box centre and largest extent for a mesh outside :data:`SCALE_FREE_RANGE`
    or far from the origin (a 1 mm sphere collapsed inwards in the quadric collapse, |r/R - 1| = 0.87, and
    came back from xatlas as an empty atlas), and the identity (zeros, 1.0) for ordinary meshes, whose results
    then stay exactly what they were (rescaling them changes which edges collapse first and how charts grow:
    the soft-fringe case's silhouette band lost 0.24 dB)."""
    positions = np.asarray(positions, dtype=np.float64)
    lo, hi = positions.min(axis=0), positions.max(axis=0)
    centre, size = 0.5 * (lo + hi), float((hi - lo).max())
    ordinary = SCALE_FREE_RANGE[0] <= size <= SCALE_FREE_RANGE[1] and float(np.abs(centre).max()) <= 100.0 * size
    if ordinary or size <= 0.0:
        return np.zeros(3), 1.0
    return centre, size
