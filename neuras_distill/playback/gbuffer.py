"""``GBuffer``: what the rasterizer hands the neural shader, per pixel of each camera."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GBuffer:
    """Rasterized mesh attributes for N cameras of size H x W (row 0 = top of the image).

    Attributes:
        uv: (N, H, W, 2) float32 interpolated texture coordinates (MeshData.uvs convention); 0 where uncovered.
        face_id: (N, H, W) int32 index of the visible face, -1 where no face covers the pixel centre.
        coverage: (N, H, W) bool, face_id >= 0.
        depth: (N, H, W) float32 distance along the camera's -z axis (view-space depth), inf where uncovered.
        normal: (N, H, W, 3) float32 unit shading normal (interpolated ``MeshData.vertex_normals``, normalized
            per pixel exactly as the bundle's fragment shader does), 0 where uncovered; None when not rasterized.
    """

    uv: np.ndarray
    face_id: np.ndarray
    coverage: np.ndarray
    depth: np.ndarray
    normal: np.ndarray | None = None

    def __repr__(self) -> str:
        return (f"GBuffer(uv={self.uv.shape} {self.uv.dtype}, face_id={self.face_id.shape} {self.face_id.dtype}, "
                f"covered={float(self.coverage.mean()):.3f})")
