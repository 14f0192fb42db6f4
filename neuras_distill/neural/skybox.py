"""Neural skyboxes (NeuRas §3): L nested cube layers around the scene that hold everything far away.

Owns: :class:`SkyboxLayers` (the geometry: centre, half sizes, face resolution, the ray -> atlas-uv mapping
that ``bake/glsl_sky.py`` reproduces in GLSL), :class:`SkyboxShader` (feature -> opacity, then colour from
an intermediate feature and the view direction), :class:`SkyboxModel` (layers + feature atlas with its own
codebook + shader, composited front to back) and :func:`plan_layers` (default distances, validation).

Frames and precision: every position here is *relative to the layers' centre* (``SkyboxLayers.center``,
float64 world coordinates, the scene centre), so kilometre-sized layers and scenes kilometres from the world
origin keep float32 precision. Callers subtract the centre in float64 before converting to float32.

Geometry. Layer ``l`` is the axis-aligned cube ``|p|_inf <= r_l`` around the centre, ``r_0 < r_1 < ...``.
Every camera lies inside the innermost cube, so each ray leaves each cube exactly once, at
``t = min_k (sign(d_k) r - p_k) / d_k``; the exit face is ``f = 2k + (d_k < 0)`` (+x, -x, +y, -y, +z, -z),
with in-face coordinates ``(s, q) = (p[(k+1)%3], p[(k+2)%3]) / r`` in [-1, 1].

Ground (optional, :class:`SkyboxGround`). Layers that hold a ground are cut by a floor ``n . p = h_l`` (unit
``n`` the up direction, ``h_l`` below every camera): a ray going down (``n . d < 0``) that meets the floor
before it leaves the cube, at ``t_g = (h_l - n . o) / (n . d) < t``, ends there, and the floor point is stored
on the cube's bottom face (the face of the axis ``k = argmax |n_k|`` that looks down), at the same in-face
coordinates of the hit. So a flat ground is painted where it lies, not on the walls of a cube around the
scene: it does not slide against the mesh's ground as the camera moves (a ground-projected skybox).

Atlas. All faces of all layers share one feature atlas of ``(2 F L) x (3 F)`` texels (F = face resolution):
face ``f`` of layer ``l`` is the F x F block at column ``(f % 3) F`` and row ``(2 l + f // 3) F``. Texel
coordinates inside a face are clamped to ``[0.5, F - 0.5]`` so bilinear filtering never reads a neighbouring
face (no gutters needed). The atlas is a :class:`NeuralTextureModel` used for its features only (its own
one-layer shader is unused), so it gets the same vector quantization, touched-texel fill and baking as the
mesh atlas, with its own codebook as in the paper.

Compositing: ``rgb = sum_l c_l a_l prod_{j<l} (1 - a_j)``; the outermost layer's opacity is fixed to 1, so
every ray that misses the mesh ends somewhere (the sky).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from ..config import SkyboxConfig
from ..errors import BadInputError
from .model import NeuralTextureModel

#: Direction components smaller than this are treated as this (positive) value in the exit computation,
#: identically in torch and GLSL (no division by zero).
TINY = 1e-20


@dataclass
class SkyboxGround:
    """The floors that cut the layers (module docstring, "Ground").

    Attributes:
        normal: (3,) float64 unit up direction, world frame.
        heights: (L,) float64 floor of each layer along ``normal``, relative to the layers' centre.
    """

    normal: np.ndarray
    heights: np.ndarray

    def __post_init__(self) -> None:
        self.normal = np.asarray(self.normal, dtype=np.float64).reshape(3)
        self.heights = np.asarray(self.heights, dtype=np.float64).reshape(-1)
        if not (np.isfinite(self.normal).all() and np.isfinite(self.heights).all()):
            raise BadInputError("a skybox ground needs a finite normal and finite heights")
        norm = float(np.linalg.norm(self.normal))
        if not norm > 0:
            raise BadInputError("a skybox ground needs a non-zero normal")
        self.normal = self.normal / norm

    @property
    def axis(self) -> int:
        """The cube axis closest to the normal: the floor is stored on that axis's downward face."""
        return int(np.argmax(np.abs(self.normal)))

    @property
    def face(self) -> int:
        """Index of the cube face that looks down (``2 k + 1`` when ``n_k > 0``)."""
        return 2 * self.axis + int(self.normal[self.axis] > 0)

    def to_json(self) -> dict:
        return {"normal": self.normal.tolist(), "heights": self.heights.tolist()}


@dataclass
class SkyboxLayers:
    """Nested cube layers.

    Attributes:
        center: (3,) float64 world position of the common centre.
        half_sizes: (L,) float64 half side lengths r_l in world units, strictly increasing.
        resolution: F, texels along a face side.
        ground: the floors that cut the layers, or None (pure cubes).
    """

    center: np.ndarray
    half_sizes: np.ndarray
    resolution: int
    ground: SkyboxGround | None = None

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.half_sizes = np.asarray(self.half_sizes, dtype=np.float64).reshape(-1)
        self.resolution = int(self.resolution)
        r = self.half_sizes
        if r.size < 1:
            raise BadInputError("skyboxes need at least one layer")
        if not np.isfinite(r).all() or not np.isfinite(self.center).all():
            raise BadInputError(f"skybox distances must be finite, got {r.tolist()}")
        if (r <= 0).any() or (np.diff(r) <= 0).any():
            raise BadInputError(f"skybox layers must nest: distances must be positive and strictly increasing, "
                                f"got {[round(float(x), 4) for x in r]}")
        if not 2 <= self.resolution <= 4096:
            raise BadInputError(f"skybox face resolution must be in 2..4096 texels, got {self.resolution}")
        if self.ground is not None and self.ground.heights.size != r.size:
            raise BadInputError(f"a skybox ground needs one height per layer ({r.size}), "
                                f"got {self.ground.heights.size}")

    @property
    def num_layers(self) -> int:
        return int(self.half_sizes.size)

    @property
    def atlas_size(self) -> tuple[int, int]:
        """(height, width) of the shared feature atlas: (2 F L, 3 F)."""
        return 2 * self.resolution * self.num_layers, 3 * self.resolution

    def relative(self, points: np.ndarray | torch.Tensor) -> torch.Tensor:
        """World points (..., 3) -> float32 tensor relative to the centre (subtracted in float64)."""
        p = np.asarray(points.detach().cpu().numpy() if torch.is_tensor(points) else points, dtype=np.float64)
        return torch.from_numpy((p - self.center).astype(np.float32))

    def check_cameras(self, camera_centers) -> None:
        """BadInputError unless every camera centre (N, 3) world lies strictly inside the innermost layer."""
        p = np.asarray(camera_centers, dtype=np.float64).reshape(-1, 3) - self.center
        reach = float(np.abs(p).max()) if p.size else 0.0
        if reach >= self.half_sizes[0]:
            raise BadInputError(f"the innermost skybox layer (half size {self.half_sizes[0]:.4g}) does not enclose "
                                f"every camera (one is {reach:.4g} from the centre along an axis); use a larger "
                                "skybox near distance")
        if self.ground is not None and p.size:
            lowest = float((p @ self.ground.normal).min())
            if lowest <= float(self.ground.heights.max()):
                raise BadInputError(f"a skybox ground lies above a camera (height {self.ground.heights.max():.4g}, "
                                    f"lowest camera {lowest:.4g}): every floor must lie below the cameras")

    def atlas_uv(self, origins: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
        """Atlas coordinates where rays leave each layer.

        Args:
            origins: (B, 3) float32 ray origins relative to ``center`` (inside the innermost layer).
            dirs: (B, 3) float32 unit directions of travel.

        Returns:
            (L, B, 2) float32 uv in the atlas (u right, v up; :func:`bilinear_corners` convention).
        """
        f_res = float(self.resolution)
        h_atlas, w_atlas = self.atlas_size
        d = torch.where(dirs.abs() < TINY, torch.full_like(dirs, TINY), dirs)
        sgn = torch.where(d < 0, -torch.ones_like(d), torch.ones_like(d))
        ground = self.ground
        if ground is not None:
            n = torch.from_numpy(ground.normal.astype(np.float32))
            d_up, o_up = d @ n, origins @ n                                      # (B,) each
            down = d_up < -TINY
            d_up_safe = torch.where(down, d_up, torch.full_like(d_up, -1.0))
        out = []
        for layer, r in enumerate(self.half_sizes.astype(np.float32).tolist()):
            t = (sgn * r - origins) / d                                          # (B, 3)
            k = torch.argmin(t, dim=1)                                           # first minimum, as GLSL
            tmin = t.gather(1, k[:, None])
            neg = (d.gather(1, k[:, None])[:, 0] < 0).long()
            if ground is not None:                                               # the floor, where it comes first
                t_floor = (float(np.float32(ground.heights[layer])) - o_up) / d_up_safe
                floor = down & (t_floor < tmin[:, 0])
                tmin = torch.where(floor[:, None], t_floor[:, None], tmin)
                k = torch.where(floor, torch.full_like(k, ground.axis), k)
                neg = torch.where(floor, torch.full_like(neg, ground.face % 2), neg)
            hit = origins + tmin * d
            a = hit.gather(1, ((k + 1) % 3)[:, None])[:, 0] / r
            b = hit.gather(1, ((k + 2) % 3)[:, None])[:, 0] / r
            face = 2 * k + neg
            x = ((a * 0.5 + 0.5) * f_res).clamp(0.5, f_res - 0.5)
            y = ((b * 0.5 + 0.5) * f_res).clamp(0.5, f_res - 0.5)
            col = (face % 3).float()
            row = (2 * layer + torch.div(face, 3, rounding_mode="floor")).float()
            out.append(torch.stack([(col * f_res + x) / w_atlas, (row * f_res + y) / h_atlas], dim=1))
        return torch.stack(out)

    def to_json(self) -> dict:
        out = {"center": self.center.tolist(), "half_sizes": self.half_sizes.tolist(),
               "resolution": self.resolution}
        if self.ground is not None:
            out["ground"] = self.ground.to_json()
        return out

    @classmethod
    def from_json(cls, data: dict) -> "SkyboxLayers":
        ground = data.get("ground")
        return cls(np.asarray(data["center"]), np.asarray(data["half_sizes"]), int(data["resolution"]),
                   None if ground is None else SkyboxGround(np.asarray(ground["normal"]),
                                                            np.asarray(ground["heights"])))


def plan_layers(aabb, camera_centers, *, num_layers: int = 4, near: float | None = None,
                far: float | None = None, resolution: int = 64) -> SkyboxLayers:
    """Default layers around the foreground box ``aabb`` (2, 3) world.

    Centre: the box centre. ``near`` (default: the larger of the box's half diagonal and 1.25x the farthest
    camera along an axis) and ``far`` (default 16x near) are half sizes; the layers between are spaced
    geometrically, as the paper's 150 m .. 2.4 km. Raises BadInputError when they do not nest or the innermost
    does not enclose every camera.
    """
    aabb = np.asarray(aabb.detach().cpu().numpy() if torch.is_tensor(aabb) else aabb, np.float64).reshape(2, 3)
    center = 0.5 * (aabb[0] + aabb[1])
    cams = np.asarray(camera_centers, np.float64).reshape(-1, 3) - center
    if int(num_layers) < 1:
        raise BadInputError(f"skybox layer count must be at least 1, got {num_layers}")
    if near is None:
        near = max(0.5 * float(np.linalg.norm(aabb[1] - aabb[0])), 1.25 * float(np.abs(cams).max(initial=0.0)))
    if far is None:
        far = 16.0 * near
    near, far = float(near), float(far)
    if num_layers == 1:
        sizes = [near]
    else:
        if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far):
            raise BadInputError(f"skybox distances must nest: need 0 < near < far, got near={near:g}, far={far:g}")
        sizes = np.geomspace(near, far, int(num_layers))
    layers = SkyboxLayers(center, np.asarray(sizes), resolution)
    layers.check_cameras(camera_centers)
    return layers


class SkyboxShader(nn.Module):
    """Per-layer MLP: h = relu(W1 f + b1); opacity = sigmoid(w_a h + b_a);
    rgb = sigmoid(W3 relu(W2 [h, d] + b2) + b3)."""

    def __init__(self, feature_dim: int, hidden: int = 16) -> None:
        super().__init__()
        self.feature_dim, self.hidden = int(feature_dim), int(hidden)
        self.l1 = nn.Linear(self.feature_dim, self.hidden)
        self.alpha = nn.Linear(self.hidden, 1)
        self.l2 = nn.Linear(self.hidden + 3, self.hidden)
        self.l3 = nn.Linear(self.hidden, 3)

    def forward(self, features: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """features (B, D), dirs (B, 3) -> rgb (B, 3), opacity (B,), both in (0, 1)."""
        h = torch.relu(self.l1(features))
        alpha = torch.sigmoid(self.alpha(h))[:, 0]
        rgb = torch.sigmoid(self.l3(torch.relu(self.l2(torch.cat([h, dirs.to(h.dtype)], dim=-1)))))
        return rgb, alpha

    def weights(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """{"l1", "alpha", "l2", "l3"}: (weight (out, in), bias (out,)) float32 numpy, for baking."""
        return {name: (layer.weight.detach().float().cpu().numpy(), layer.bias.detach().float().cpu().numpy())
                for name, layer in (("l1", self.l1), ("alpha", self.alpha), ("l2", self.l2), ("l3", self.l3))}


class SkyboxModel(nn.Module):
    """(ray origin relative to the centre, direction) -> colour of everything behind the mesh.

    Args:
        layers: :class:`SkyboxLayers`.
        feature_dim: D channels per texel; num_codes: K codes of the skybox codebook; hidden: MLP width.
    """

    def __init__(self, layers: SkyboxLayers, feature_dim: int = SkyboxConfig.feature_dim,
                 num_codes: int = 4096, hidden: int = SkyboxConfig.hidden) -> None:
        super().__init__()
        self.layers = layers
        h, w = layers.atlas_size
        self.atlas = NeuralTextureModel(h, w, feature_dim=feature_dim, num_codes=num_codes, hidden=1,
                                        num_layers=1, output_layers=1, use_viewdir=False,
                                        quantize_above=0,    # sky: always k-means
                                        coarse_factor=1)   # its atlas is six faces a layer side by side
        self.shader = SkyboxShader(feature_dim, hidden)

    @property
    def feature_dim(self) -> int:
        return self.atlas.feature_dim

    def forward(self, origins: torch.Tensor, dirs: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """origins (B, 3) relative to the centre, dirs (B, 3) unit -> rgb (B, 3), aux {"vq_loss"}."""
        n_layers, b = self.layers.num_layers, origins.shape[0]
        uv = self.layers.atlas_uv(origins.float(), dirs.float())                 # (L, B, 2)
        feats, aux = self.atlas.features(uv.reshape(-1, 2))
        rgb, alpha = self.shader(feats, dirs.float().repeat(n_layers, 1))
        rgb, alpha = rgb.view(n_layers, b, 3), alpha.view(n_layers, b)
        alpha = torch.cat([alpha[:-1], torch.ones_like(alpha[-1:])], dim=0)      # the outermost layer is opaque
        out = torch.zeros(b, 3, dtype=rgb.dtype, device=rgb.device)
        trans = torch.ones(b, dtype=rgb.dtype, device=rgb.device)
        for layer in range(n_layers):
            out = out + (trans * alpha[layer])[:, None] * rgb[layer]
            trans = trans * (1.0 - alpha[layer])
        return out, {"vq_loss": aux["vq_loss"]}

    def dense_parameters(self) -> list[nn.Parameter]:
        """Parameters trained with dense Adam: the shader and the codebook (the atlas uses SparseAdam)."""
        params = list(self.shader.parameters())
        if self.atlas.vq is not None:
            params.append(self.atlas.vq.codebook)
        return params


__all__ = ["SkyboxGround", "SkyboxLayers", "SkyboxShader", "SkyboxModel", "plan_layers", "TINY"]
