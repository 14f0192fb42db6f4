"""Embedded synthetic scenes: the ``SCENES`` registry, ``make_scene``, and the Stanford-bunny SDF field.

This module owns:

* :data:`SCENES` (name -> factory) and :func:`make_scene` (``kind`` ``"sdf"`` or ``"density"``, default the
  scene's own). Names:
  ``"bunny"`` (the default/demo scene), ``"bunny-matte"`` (the same without its highlight), ``"sphere"``,
  ``"torus"``, ``"street"`` (:mod:`.street`), ``"city"`` and ``"city-small"`` (:mod:`.city`), ``"blocks"`` (six
  blocks on a ground slab, :class:`~.analytic.BlocksSDF`: a scene small enough to tile in a test),
  ``"gradient-ball"`` (:mod:`.gradient_ball`, a density field only).
* :class:`BunnyField`: the real Stanford bunny (``neuras_distill/data/bunny.obj``, y-up in the file) rotated
  to z-up, scaled to 1 unit tall, standing on a rounded disc. Its SDF is computed once with libigl
  (``geometry.raycast.signed_distance``: the distance to the nearest triangle, signed by the generalized
  winding number, since the scan has small holes; they all sit at the bottom, inside the base) and baked to a
  float32 grid cached on disk (``$NEURAS_CACHE_DIR`` or ``~/.cache/neuras-distill/``, keyed by a hash of the
  OBJ bytes and the bake parameters, written atomically). Evaluation: trilinear ``grid_sample`` of the bunny
  grid, united (min) with the analytic SDF of the base; normals from a trilinear gradient grid (central
  differences). Radiance: procedural albedo with fine detail times soft
  diffuse lighting, plus a Blinn-Phong lobe on the bunny (view-dependent), clipped to [0, 1].

libigl is reached only through :mod:`neuras_distill.geometry.raycast` (its one importer), which
:func:`_bake_bunny_sdf` imports lazily: the scenes need it only when a bunny grid is baked.
World frame of every scene: z up, units ~ the object's size (the bunny is 1 unit tall).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as F

from ..errors import BadInputError
from ..fields.wrappers import SDFToDensityField
from .analytic import BlocksSDF, SphereSDF, TorusSDF, orbit_framing, smoothstep
from .city import CITY_BETA, make_city, make_small_city
from .gradient_ball import make_gradient_ball
from .street import STREET_BETA, make_street

BUNNY_OBJ = Path(__file__).resolve().parent.parent / "data" / "bunny.obj"
BAKE_VERSION = 2

# bunny scene parameters (world units; the bunny is 1 unit tall, its lowest point at z = 0)
BUNNY_HEIGHT = 1.0
BASE_RADIUS = 0.62       # disc radius (the bunny's largest horizontal reach is 0.57)
BASE_TOP = 0.045         # the bunny sinks 0.045 into the base: covers the scan's holes (all at z < 0.041)
BASE_THICKNESS = 0.09
BASE_ROUNDING = 0.02
AABB_MARGIN = 0.02
GRID_RESOLUTION = 160    # samples along the longest aabb axis
BUNNY_INV_S = 1000.0     # NeuS sharpness: the opacity ramp is ~ 10 / inv_s = 0.01 units wide
BUNNY_BETA = 0.003       # VolSDF Laplace scale for the density variant (world units)

LIGHT_DIR = (0.45, -0.35, 0.82)
AMBIENT = 0.32
WRAP = 0.3
GLOSS_STRENGTH = 0.25
GLOSS_EXPONENT = 12.0


# ---------------------------------------------------------------------------------------------- cache
def cache_dir() -> Path:
    """Where baked grids live: ``$NEURAS_CACHE_DIR`` or ``~/.cache/neuras-distill``."""
    env = os.environ.get("NEURAS_CACHE_DIR")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "neuras-distill"


def _atomic_save_npz(path: Path, **arrays: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp.npz", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


# ---------------------------------------------------------------------------------------------- mesh
def load_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and triangle faces (F, 3) int64 (0-based) of a simple OBJ file."""
    verts, faces = [], []
    for line in Path(path).read_text().splitlines():
        if line.startswith("v "):
            verts.append([float(v) for v in line.split()[1:4]])
        elif line.startswith("f "):
            idx = [int(tok.split("/")[0]) for tok in line.split()[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not verts or not faces:
        raise BadInputError(f"{path} has no vertices or faces; expected a triangle mesh OBJ")
    return np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def bunny_mesh() -> tuple[np.ndarray, np.ndarray]:
    """The bunny in the scene frame: z up (file y -> z), 1 unit tall, lowest point at z = 0, centred in x, y."""
    v, f = load_obj(BUNNY_OBJ)
    v = np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1)  # rotation +90 deg about x: y-up -> z-up
    lo, hi = v.min(0), v.max(0)
    scale = BUNNY_HEIGHT / (hi[2] - lo[2])
    shift = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
    return (v - shift) * scale, f


def base_sdf(x: torch.Tensor) -> torch.Tensor:
    """Signed distance (N,) of the rounded disc under the bunny (axis z, top at BASE_TOP)."""
    zc = BASE_TOP - 0.5 * BASE_THICKNESS
    r = x[:, :2].norm(dim=-1)
    qx = r - (BASE_RADIUS - BASE_ROUNDING)
    qz = (x[:, 2] - zc).abs() - (0.5 * BASE_THICKNESS - BASE_ROUNDING)
    outside = torch.stack([qx, qz], dim=-1).clamp(min=0.0).norm(dim=-1)
    inside = torch.maximum(qx, qz).clamp(max=0.0)
    return outside + inside - BASE_ROUNDING


def _scene_aabb(vertices: np.ndarray) -> np.ndarray:
    lo = np.minimum(vertices.min(0), [-BASE_RADIUS, -BASE_RADIUS, BASE_TOP - BASE_THICKNESS])
    hi = np.maximum(vertices.max(0), [BASE_RADIUS, BASE_RADIUS, BASE_TOP])
    return np.stack([lo - AABB_MARGIN, hi + AABB_MARGIN]).astype(np.float32)


def _bake_bunny_sdf(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, cell: float,
                    shape: tuple[int, int, int]) -> np.ndarray:
    """Signed distance of the bunny mesh at the grid points, float32 array indexed [iz, iy, ix]."""
    from ..geometry.raycast import raycasting_scene, signed_distance  # lazy: it imports libigl

    scene = raycasting_scene(vertices, faces)
    nz, ny, nx = shape
    axes = [origin[k] + cell * np.arange(n, dtype=np.float64) for k, n in enumerate((nx, ny, nz))]
    zz, yy, xx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    pts = np.stack([xx, yy, zz], axis=-1).astype(np.float32)
    sdf = signed_distance(scene, pts)
    return _fix_sign_islands(sdf.astype(np.float32).reshape(shape))


def _fix_sign_islands(sdf: np.ndarray) -> np.ndarray:
    """Remove sign errors of the winding-number sign (near the scan's holes): negative
    islands apart from the largest inside region become positive, positive pockets not connected to the
    grid border become negative. The bunny is one closed body, so this is exact for it."""
    from scipy import ndimage

    sdf = sdf.copy()
    lab, n = ndimage.label(sdf < 0)
    if n > 1:
        sizes = np.bincount(lab.ravel())[1:]
        stray = (lab > 0) & (lab != 1 + int(np.argmax(sizes)))
        sdf[stray] = np.abs(sdf[stray])
    lab, n = ndimage.label(sdf >= 0)
    if n > 1:
        border = np.unique(np.concatenate([lab[[0, -1]].ravel(), lab[:, [0, -1]].ravel(), lab[..., [0, -1]].ravel()]))
        pocket = (lab > 0) & ~np.isin(lab, border)
        sdf[pocket] = -np.abs(sdf[pocket])
    return sdf


def load_bunny_grid(resolution: int = GRID_RESOLUTION) -> dict:
    """The baked bunny SDF grid (from the cache, baking it on a miss).

    Returns ``{"sdf": (nz, ny, nx) float32, "origin": (3,) grid point (0,0,0) in world, "cell": float,
    "aabb": (2, 3) scene box, "vertices": (V, 3), "faces": (F, 3)}``.
    """
    vertices, faces = bunny_mesh()
    aabb = _scene_aabb(vertices)
    extent = aabb[1] - aabb[0]
    cell = float(extent.max()) / (resolution - 1)
    nx, ny, nz = (int(math.ceil(float(e) / cell - 1e-6)) + 1 for e in extent)
    params = {"v": BAKE_VERSION, "res": resolution, "aabb": aabb.round(6).tolist(), "height": BUNNY_HEIGHT,
              "sign": "winding number"}
    key = hashlib.sha256(BUNNY_OBJ.read_bytes() + json.dumps(params, sort_keys=True).encode()).hexdigest()[:20]
    path = cache_dir() / f"bunny_sdf_{key}.npz"
    sdf = None
    if path.exists():
        try:
            with np.load(path) as data:
                sdf = data["sdf"]
            if sdf.shape != (nz, ny, nx):
                sdf = None
        except (OSError, ValueError, KeyError):
            sdf = None  # a damaged cache file is rebuilt
    if sdf is None:
        sdf = _bake_bunny_sdf(vertices, faces, aabb[0].astype(np.float64), cell, (nz, ny, nx))
        _atomic_save_npz(path, sdf=sdf)
    return {"sdf": sdf, "origin": aabb[0].copy(), "cell": cell, "aabb": aabb, "vertices": vertices,
            "faces": faces, "cache_path": path}


# ---------------------------------------------------------------------------------------------- field
class BunnyField:
    """The bunny-on-a-disc scene as an SDF field (kind ``"sdf"``), z up, 1 unit tall.

    Members: ``kind``, ``aabb`` (2, 3), ``geometry(x)`` (N, 3) -> (N,), ``radiance(x, d)`` -> (N, 3),
    ``exact_sdf(x)`` (same as geometry: the baked SDF), ``normal(x)`` (N, 3), ``inv_s``,
    ``background_color`` (white), ``default_cameras(n, width, height)``, ``vertices``/``faces`` (the
    scene-frame mesh, for tests).
    """

    kind = "sdf"

    def __init__(self, resolution: int = GRID_RESOLUTION, inv_s: float = BUNNY_INV_S,
                 gloss: float = GLOSS_STRENGTH):
        self.gloss = float(gloss)             # 0: a matte bunny (no view-dependent highlight)
        grid = load_bunny_grid(resolution)
        self.vertices, self.faces = grid["vertices"], grid["faces"]
        self.cache_path = grid["cache_path"]
        self.aabb = torch.as_tensor(grid["aabb"], dtype=torch.float32)
        self.inv_s = float(inv_s)
        self.background_color = torch.ones(3)
        sdf = np.ascontiguousarray(grid["sdf"], dtype=np.float32)
        cell = grid["cell"]
        self._cell = float(cell)
        self._origin = torch.as_tensor(grid["origin"], dtype=torch.float32)
        nz, ny, nx = sdf.shape
        self._grid_max = self._origin + cell * torch.tensor([nx - 1, ny - 1, nz - 1], dtype=torch.float32)
        self._scale = 2.0 / (self._grid_max - self._origin)
        gz, gy, gx = np.gradient(sdf, cell)
        self._sdf_grid = torch.from_numpy(sdf)[None, None]  # (1, 1, nz, ny, nx)
        self._grad_grid = torch.from_numpy(np.stack([gx, gy, gz]).astype(np.float32))[None]  # (1, 3, ...)
        self._light = F.normalize(torch.tensor(LIGHT_DIR), dim=0)

    def __repr__(self) -> str:
        return (f"BunnyField(aabb={self.aabb.tolist()}, grid={tuple(self._sdf_grid.shape[2:])}, "
                f"inv_s={self.inv_s})")

    # -- grid lookups
    def _sample(self, grid: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Trilinear lookup of ``grid`` (1, C, nz, ny, nx) at points x (N, 3) (clamped to the grid) -> (N, C)."""
        g = ((x - self._origin) * self._scale - 1.0).clamp(-1.0, 1.0)
        out = F.grid_sample(grid, g.view(1, -1, 1, 1, 3), mode="bilinear", padding_mode="border",
                            align_corners=True)
        return out.view(grid.shape[1], -1).T

    def bunny_sdf(self, x: torch.Tensor) -> torch.Tensor:
        """(N,) baked distance to the bunny alone; outside the grid: distance to the grid box added."""
        x = x.float()
        inside = torch.minimum(torch.maximum(x, self._origin), self._grid_max)
        return self._sample(self._sdf_grid, x)[:, 0] + (x - inside).norm(dim=-1)

    def exact_sdf(self, x: torch.Tensor) -> torch.Tensor:
        """(N,) signed distance of the scene (bunny united with the base), negative inside."""
        x = x.float()
        return torch.minimum(self.bunny_sdf(x), base_sdf(x))

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        return self.exact_sdf(x)

    def _normals(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Unit normals (N, 3) and the bunny mask (N,) bool (True where the bunny is the nearer part)."""
        on_bunny = self.bunny_sdf(x) <= base_sdf(x)
        n = self._sample(self._grad_grid, x)
        eps = 1e-3
        offs = torch.eye(3) * eps
        xb = x[~on_bunny]
        if xb.shape[0]:
            fb = base_sdf(torch.cat([xb[:, None] + offs, xb[:, None] - offs], 1).reshape(-1, 3)).view(-1, 2, 3)
            n[~on_bunny] = fb[:, 0] - fb[:, 1]
        return F.normalize(n, dim=-1, eps=1e-12), on_bunny

    def normal(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) unit outward normals of the scene."""
        return self._normals(x.float())[0]

    # -- appearance
    def albedo(self, x: torch.Tensor, on_bunny: torch.Tensor) -> torch.Tensor:
        """(N, 3) procedural albedo: three-colour marbling with fine speckle on the bunny, rings on the base."""
        px, py, pz = x[:, 0], x[:, 1], x[:, 2]
        warp = 0.6 * torch.sin(9.0 * px + 4.0 * pz) + 0.4 * torch.sin(11.0 * py - 7.0 * pz)
        v = (torch.sin(14.0 * pz + 3.0 * warp) + 0.5 * torch.sin(23.0 * px - 17.0 * py + 2.0 * warp)
             + 0.25 * torch.sin(41.0 * py + 37.0 * pz + warp))
        t = torch.sigmoid(2.5 * v)[:, None]
        cream = torch.tensor([0.95, 0.88, 0.74])
        caramel = torch.tensor([0.78, 0.47, 0.24])
        cocoa = torch.tensor([0.36, 0.22, 0.15])
        c = cream + (caramel - cream) * t
        speck = smoothstep(0.55, 0.85, torch.sin(83.0 * px + 5.0 * warp) * torch.sin(79.0 * py - 71.0 * pz))
        c = c + (cocoa - c) * (0.8 * speck)[:, None]
        r = x[:, :2].norm(dim=-1)
        ring = 0.5 + 0.5 * torch.sin(70.0 * r + 2.0 * torch.sin(5.0 * torch.atan2(py, px)))
        base = torch.tensor([0.50, 0.57, 0.66]) * (0.88 + 0.12 * ring)[:, None]
        return torch.where(on_bunny[:, None], c, base)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3), d (N, 3) unit directions of travel -> (N, 3) colour in [0, 1].

        albedo * (ambient + soft wrapped diffuse) + Blinn-Phong highlight (bunny only)."""
        x, d = x.float(), d.float()
        n, on_bunny = self._normals(x)
        ndl = (n * self._light).sum(-1)
        shade = AMBIENT + (1.0 - AMBIENT) * ((ndl + WRAP) / (1.0 + WRAP)).clamp(min=0.0)
        rgb = self.albedo(x, on_bunny) * shade[:, None]
        h = F.normalize(self._light - d, dim=-1)
        spec = self.gloss * (n * h).sum(-1).clamp(min=0.0) ** GLOSS_EXPONENT * on_bunny.float()
        return (rgb + spec[:, None]).clamp(0.0, 1.0)

    def default_cameras(self, n: int, width: int = 512, height: int = 512):
        """Helix orbit (z up, elevation 15..50 degrees, 40 degree fov) framing the bunny and its base (the
        aabb's bounding sphere is loose around the round base, so the orbit comes in to 0.75 of it)."""
        return orbit_framing(self.aabb, n, width, height, padding=0.75)


# ---------------------------------------------------------------------------------------------- registry
def _bunny() -> BunnyField:
    return BunnyField()


def _bunny_matte() -> BunnyField:
    return BunnyField(gloss=0.0)


def _sphere() -> SphereSDF:
    return SphereSDF(center=(0.0, 0.0, 0.5), radius=0.5, inv_s=BUNNY_INV_S, gloss=GLOSS_STRENGTH)


def _torus() -> TorusSDF:
    return TorusSDF(center=(0.0, 0.0, 0.2), major=0.5, minor=0.2, inv_s=BUNNY_INV_S, gloss=GLOSS_STRENGTH)


def _blocks() -> BlocksSDF:
    return BlocksSDF(inv_s=BUNNY_INV_S)


SCENES: dict[str, Callable[[], object]] = {"bunny": _bunny, "bunny-matte": _bunny_matte, "sphere": _sphere,
                                           "torus": _torus, "street": make_street,
                                           "gradient-ball": make_gradient_ball, "city": make_city,
                                           "city-small": make_small_city, "blocks": _blocks}
DEFAULT_SCENE = "bunny"
SCENE_BETA = {"bunny": BUNNY_BETA, "bunny-matte": BUNNY_BETA, "sphere": BUNNY_BETA, "torus": BUNNY_BETA,
              "street": STREET_BETA, "city": CITY_BETA, "city-small": CITY_BETA, "blocks": BUNNY_BETA}


def make_scene(name: str = DEFAULT_SCENE, kind: str | None = None):
    """Build the embedded scene ``name`` as a field of ``kind``: ``None`` (default) gives the scene's own kind
    (``"sdf"``, or ``"density"`` for ``gradient-ball``); ``"density"`` of an SDF scene is the VolSDF Laplace
    density of the same SDF with the scene's β (same radiance, aabb, background and cameras). A density scene
    has no SDF: ``kind="sdf"`` is refused for it."""
    if name not in SCENES:
        raise BadInputError(f"unknown synthetic scene {name!r}; available: {', '.join(sorted(SCENES))}")
    if kind not in (None, "sdf", "density"):
        raise BadInputError(f"unknown field kind {kind!r} for a synthetic scene; use 'sdf' or 'density'")
    field = SCENES[name]()
    if kind is None or kind == field.kind:
        return field
    if field.kind == "density":
        raise BadInputError(f"synthetic scene {name!r} is a density field with no signed distance; "
                            "use kind 'density' (--kind density)")
    return SDFToDensityField(field, SCENE_BETA[name])
