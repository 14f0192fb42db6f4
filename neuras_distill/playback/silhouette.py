"""Soft silhouettes: a screen-space pass that blends the pixels along the mesh's coverage edge.

A field's surface fades out over a pixel or more (a NeuS opacity is a sigmoid of the SDF, a NeRF's density ramps
up), so its renders show every silhouette as a soft, partly covered edge; a rasterized mesh cuts it hard, one
sample per pixel. Multisampling (4x) softened those edges and gained 2.6 dB on the NeuS fixture, but llvmpipe
shades every sample (2.6x the frame time). This pass gets more for a fraction of that: after the mesh (and
skybox) pass, every pixel whose two diagonal 2 x 2 blocks (with its left and lower, and with its right and
upper neighbours) hold both mesh and no mesh becomes the tent filter [1 2 1] x [1 2 1] / 16 of its
neighbourhood; all other pixels pass through. The GLSL reads LINEAR-filtered 2 x 2 block means (two fetches
for the test, two more on edges). ``BundleRenderer`` runs it only on the screen tiles along the mesh's silhouette
and boundary edges (``silhouette_strips.py``; the mesh's screen box for a wrinkled surface with thousands of
them); the web player runs it over the box. Both give the same picture. Measured on
bundles against the field (same held-out views, 8-bit): NeuS fixture 32.96 -> 37.01 dB, demo
34.77 -> 36.44 dB (a 3 x 3 box instead: 36.70 / 36.46); the gradient ball, whose fringe shell already fades to
the background, is unchanged.

Coverage travels in the scene pass's alpha: the mesh shaders write 1, the clear colour and the skybox pass 0,
and a two-layer mesh's shell (``MeshData.core_faces``) :data:`SHELL_COVERAGE`, so the seam where the opaque core's
silhouette meets the shell inside the picture is an edge too. That seam is a steep step in the field's colour
(a ray grazing the core crosses the whole fringe, its neighbour outside the core only the fringe): on the
from-ngp ball (held-out 384 x 216) the core's outermost pixel held 22% of the interior's squared
error at 26.5 dB, and blending the seam alone lifted it to 29.5 dB and the interior 35.91 -> 36.58 dB. A 2 x 2
block's mean alpha equals 0, :data:`SHELL_COVERAGE` or 1 only when its four pixels are all of one kind
(0.302 is no mean of four values from {0, 0.302, 1} other than four shells; the nearest, 0.326, is 0.024 off).
Neighbours outside the image are clamped to it (no edges along the image border).

Owns: the pass's numpy
mirror :func:`blend_silhouettes` (what the torch reference applies for the GL/torch parity).
"""

from __future__ import annotations

import numpy as np

from ..bake.shader_interface import SHELL_COVERAGE


def _block_means(x: np.ndarray) -> list[np.ndarray]:
    """Means of the four 2 x 2 blocks around each pixel of (H, W[, C]) ``x`` (row 0 = top; edge-clamped), in
    the order of the GLSL fetches: left-below, right-above, right-below, left-above."""
    pad = np.pad(x, ((1, 1), (1, 1)) + ((0, 0),) * (x.ndim - 2), mode="edge").astype(np.float32)
    h, w = x.shape[:2]

    def block(r0: int, c0: int) -> np.ndarray:      # rows r0..r0+1, cols c0..c0+1 of the padded image
        return 0.25 * (pad[r0:r0 + h, c0:c0 + w] + pad[r0 + 1:r0 + 1 + h, c0:c0 + w]
                       + pad[r0:r0 + h, c0 + 1:c0 + 1 + w] + pad[r0 + 1:r0 + 1 + h, c0 + 1:c0 + 1 + w])

    return [block(1, 0), block(0, 1), block(1, 1), block(0, 0)]


def layer_coverage(face_id: np.ndarray, core_faces: int | None) -> np.ndarray:
    """(H, W) float32 coverage as the mesh shaders write it to alpha: 0 where no face is, 1 on a single-layer
    mesh or the core, :data:`SHELL_COVERAGE` on the shell (faces ``>= core_faces`` of a two-layer mesh;
    ``face_id``: (H, W) int, -1 where no face)."""
    face_id = np.asarray(face_id)
    cover = (face_id >= 0).astype(np.float32)
    if core_faces is not None:
        cover[face_id >= int(core_faces)] = SHELL_COVERAGE
    return cover


def _one_kind(mean: np.ndarray) -> np.ndarray:
    return (mean < 0.001) | (mean > 0.999) | (np.abs(mean - SHELL_COVERAGE) < 0.01)


def silhouette_edges(coverage: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose two diagonal 2 x 2 blocks (with the left and lower, and with the right and upper
    neighbours; outside the image: edge-clamped) hold more than one kind of pixel. ``coverage``: (H, W) bool
    (covered or not) or float32 from :func:`layer_coverage` (empty, shell, core)."""
    cover = np.asarray(coverage, np.float32)
    a, b = _block_means(np.round(cover * 255.0) / 255.0)[:2]        # the alpha the RGBA8 scene holds
    return ~(_one_kind(a) & _one_kind(b) & (np.abs(a - b) < 0.01))


def blend_silhouettes(image: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """The pass on an (H, W, 3) float image with its (H, W) mesh coverage: edge pixels (:func:`silhouette_edges`)
    become the tent filter [1 2 1] x [1 2 1] / 16 of their neighbourhood (the mean of the four 2 x 2 blocks)."""
    img = np.asarray(image, np.float32)
    tent = sum(_block_means(img)) / 4.0
    return np.where(silhouette_edges(coverage)[..., None], tent, img).astype(np.float32)


__all__ = ["SHELL_COVERAGE", "layer_coverage",
           "silhouette_edges", "blend_silhouettes"]
