"""Soft silhouettes: a screen-space pass that blends the pixels along the mesh's coverage edge.

A field's surface fades out over a pixel or more (a NeuS opacity is a sigmoid of the SDF, a NeRF's density ramps
up), so its renders show every silhouette as a soft, partly covered edge; a rasterized mesh cuts it hard, one
sample per pixel. Multisampling (4x) softened those edges and gained 2.6 dB on the NeuS fixture, but llvmpipe
shades every sample (2.6x the frame time). This pass gets more for a fraction of that: after the mesh (and
skybox) pass, every pixel whose 4-neighbourhood holds both mesh and no mesh is replaced by the mean of its 3 x 3
neighbourhood; all other pixels pass through. Measured on trained bundles against the field (same held-out
views): NeuS fixture 32.96 -> 36.70 dB, demo 34.77 -> 36.46 dB; the gradient ball, whose fringe shell already
fades to the background, is unchanged.

Coverage travels in the scene pass's alpha: the mesh shaders write 1, the clear colour and the skybox pass 0.
Neighbours outside the image are the pixel itself (no edges along the image border).

Owns: the GLSL of the pass (:data:`SILHOUETTE_VERTEX_SHADER`, :data:`SILHOUETTE_FRAGMENT_SHADER`) and its numpy
mirror :func:`blend_silhouettes` (what the torch reference applies for the GL/torch parity).
"""

from __future__ import annotations

import numpy as np

#: A full-screen triangle (no vertex buffer: ``gl_VertexID`` 0, 1, 2).
SILHOUETTE_VERTEX_SHADER = """#version 330
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
"""

SILHOUETTE_FRAGMENT_SHADER = """#version 330
uniform sampler2D u_scene;  // RGBA8 scene pass: rgb, a = 1 where the mesh drew
out vec4 f_color;
void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 hi = textureSize(u_scene, 0) - 1;
    vec4 c = texelFetch(u_scene, p, 0);
    float l = texelFetch(u_scene, clamp(p + ivec2(-1, 0), ivec2(0), hi), 0).a;
    float r = texelFetch(u_scene, clamp(p + ivec2(1, 0), ivec2(0), hi), 0).a;
    float d = texelFetch(u_scene, clamp(p + ivec2(0, -1), ivec2(0), hi), 0).a;
    float u = texelFetch(u_scene, clamp(p + ivec2(0, 1), ivec2(0), hi), 0).a;
    float lo = min(min(min(l, r), min(d, u)), c.a);
    float up = max(max(max(l, r), max(d, u)), c.a);
    if (lo < 0.5 && up > 0.5) {
        vec3 sum = vec3(0.0);
        for (int dy = -1; dy <= 1; ++dy)
            for (int dx = -1; dx <= 1; ++dx)
                sum += texelFetch(u_scene, clamp(p + ivec2(dx, dy), ivec2(0), hi), 0).rgb;
        f_color = vec4(sum / 9.0, 1.0);
    } else {
        f_color = vec4(c.rgb, 1.0);
    }
}
"""


def silhouette_edges(coverage: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose 4-neighbourhood (itself included; outside the image: itself) holds both covered
    and uncovered pixels."""
    cov = np.pad(np.asarray(coverage, bool), 1, mode="edge")
    stack = np.stack([cov[1:-1, 1:-1], cov[1:-1, :-2], cov[1:-1, 2:], cov[:-2, 1:-1], cov[2:, 1:-1]])
    return stack.any(axis=0) & ~stack.all(axis=0)


def blend_silhouettes(image: np.ndarray, coverage: np.ndarray) -> np.ndarray:
    """The pass on an (H, W, 3) float image with its (H, W) mesh coverage: edge pixels (:func:`silhouette_edges`)
    become the mean of their 3 x 3 neighbourhood (edge-clamped)."""
    img = np.asarray(image, np.float32)
    pad = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = img.shape[:2]
    mean = sum(pad[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)) / 9.0
    return np.where(silhouette_edges(coverage)[..., None], mean, img).astype(np.float32)


__all__ = ["SILHOUETTE_VERTEX_SHADER", "SILHOUETTE_FRAGMENT_SHADER", "silhouette_edges", "blend_silhouettes"]
