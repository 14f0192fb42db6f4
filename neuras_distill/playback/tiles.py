"""Several bundles drawn into one frame: the tiles of a tileset together (this module owns ``TilesRenderer``).

Each tile keeps its own ``BundleRenderer`` (its shader, atlas and codebook) on one shared OpenGL context; a frame
is one framebuffer (RGBA8 colour, 24-bit depth) cleared once to the first tile's background, then every tile's
mesh drawn into it with the same near and far planes (the union of the tiles' boxes, ``projection.near_far_for``),
so the depth test resolves which tile shows at each pixel exactly as one mesh would. Skyboxes and the
soft-silhouette pass are per-bundle passes and are not drawn here. Cameras are world cameras (each renderer
moves them into its own bundle's frame in float64).
"""

from __future__ import annotations

import numpy as np

from .context import get_context
from .projection import mesh_bounds, near_far_for


class TilesRenderer:
    """``render(cameras, i)`` -> (H, W, 3) float32 in [0, 1] (row 0 = top, 8-bit quantised) of world camera ``i``
    with every bundle of ``bundles`` in view; ``render_ids(cameras, i)`` -> ((H, W) index of the tile at each pixel,
    -1 where none; (H, W) view-axis depth)."""

    def __init__(self, bundles, ctx=None):
        from .renderer import BundleRenderer

        self.ctx = ctx if ctx is not None else get_context()
        self.bundles = list(bundles)
        self.players = [BundleRenderer(b, ctx=self.ctx, silhouette_blend=False, depth_prepass=False,
                                       shading="forward") for b in self.bundles]
        corners = [mesh_bounds(b.mesh.vertices) + np.asarray(b.origin, np.float64) for b in self.bundles]
        self.bounds = np.stack([np.min([c[0] for c in corners], 0), np.max([c[1] for c in corners], 0)])
        self.background = self.players[0].background
        self._fbos: dict = {}
        self._id_players = None

    def _fbo(self, w: int, h: int):
        if (w, h) not in self._fbos:
            color = self.ctx.renderbuffer((w, h), 4, dtype="f1")
            depth = self.ctx.depth_renderbuffer((w, h))
            self._fbos[(w, h)] = (self.ctx.framebuffer([color], depth), color, depth)
        return self._fbos[(w, h)][0]

    def _draw(self, players, cameras, i: int, background, depth: bool = False):
        h, w = int(cameras.height), int(cameras.width)
        fbo = self._fbo(w, h)
        fbo.use()
        fbo.clear(*background, 0.0, depth=1.0)
        c2w = cameras.c2w[i].double().numpy()
        near, far = near_far_for(self.bounds, c2w[:3, 3], c2w)
        for player in players:
            player.draw_mesh_into(cameras, i, (near, far))
        data = np.frombuffer(fbo.read(components=3, alignment=1, dtype="f1"), np.uint8).reshape(h, w, 3)[::-1]
        if not depth:
            return data
        z = np.frombuffer(fbo.read(attachment=-1, components=1, alignment=1, dtype="f4"), np.float32).reshape(h, w)[::-1]
        ndc = 2.0 * z.astype(np.float64) - 1.0                    # back to the view-axis distance
        view = 2.0 * near * far / np.maximum(far + near - ndc * (far - near), 1e-30)
        return data, np.where(z < 1.0, view, np.inf)

    def render(self, cameras, i: int) -> np.ndarray:
        return self._draw(self.players, cameras, i, self.background).astype(np.float32) / 255.0

    def render_ids(self, cameras, i: int) -> tuple[np.ndarray, np.ndarray]:
        """((H, W) int64 tile index per pixel (-1: no tile), (H, W) float64 view-axis depth (inf: none)): each
        tile drawn with a flat plain texture whose colour encodes its index."""
        from ..bake.plain_texture import plain_bundle
        from .renderer import BundleRenderer

        if self._id_players is None:
            self._id_players = []
            for k, b in enumerate(self.bundles):
                flat = np.zeros_like(b.plain_rgb if b.plain_rgb is not None else np.zeros((4, 4, 3), np.uint8),
                                     dtype=np.float32)
                flat[..., 0], flat[..., 1] = (k % 250 + 1) / 255.0, (k // 250) / 255.0
                self._id_players.append(BundleRenderer(plain_bundle(b, flat), ctx=self.ctx,
                                                       silhouette_blend=False, depth_prepass=False,
                                                       shading="forward"))
        rgb, depth = self._draw(self._id_players, cameras, i, (0.0, 0.0, 0.0), depth=True)
        rgb = rgb.astype(np.int64)
        return np.where(rgb[..., 0] > 0, rgb[..., 0] - 1 + 250 * rgb[..., 1], -1), depth

    def release(self) -> None:
        for player in self.players + (self._id_players or []):
            player.release()
        for fbo, color, depth in self._fbos.values():
            fbo.release()
            color.release()
            depth.release()
        self._fbos.clear()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


__all__ = ["TilesRenderer"]
