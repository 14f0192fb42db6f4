"""The plain RGB texture of a trained model: what the bundle would be without its neural shader.

Owns: :func:`texel_view_inputs`, :func:`plain_texture`, :func:`chart_mask`, :func:`pad_gutters`,
:func:`plain_texture_rgb8` (what a run stores as the bundle's ``plain_rgb.png``) and :func:`plain_bundle` (its
shader is ``glsl.plain_fragment_shader``).

Each texel's colour is the model's own output for that texel, evaluated once: the texel's (quantized) feature
through the shader of the layer that texel belongs to, with the mean view input the training views saw it
with (unit mean direction, mean facing cosine, the majority layer). Texels no training pixel saw take the inputs
of the nearest seen texel. Played with bilinear filtering in the same GL pipeline (same mesh, same UVs, same
draw calls), it is the baseline the neural shader is measured against (``report.json["plain_texture"]``) and
the texture other engines get (glTF's base colour).

Gutters: texels no bilinear lookup inside a UV chart reaches (outside the charts' texels dilated by two) take
the colour of the nearest texel that one does reach (a full nearest-texel fill, not just a few texels), so an
engine's bilinear or mipmapped sampling at a chart border never blends in unrelated colours; the texels lookups
inside the charts reach keep the model's own colour, so the bundle's bilinear playback is unchanged by the fill.

Frames: directions in the bundle's frame (the training G-buffers' frame: relative to the run's origin).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage

from .bundle import Bundle, atlas_pages
from .glsl import plain_fragment_shader


def _nearest_texel(uv: np.ndarray, height: int, width: int) -> np.ndarray:
    """(M,) int64 flat index ``j * W + i`` of the texel whose square contains each uv (clamped to the atlas)."""
    i = np.clip(np.floor(uv[:, 0] * width), 0, width - 1).astype(np.int64)
    j = np.clip(np.floor(uv[:, 1] * height), 0, height - 1).astype(np.int64)
    return j * width + i


def texel_view_inputs(uv, coverage, view_inputs, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean view input per texel over the covered training pixels.

    Args:
        uv: (N, H', W', 2) G-buffer uvs; coverage: (N, H', W') bool; view_inputs: (N, H', W', C) the model's
            view inputs of those pixels (``neural.model.view_inputs``).
    Returns:
        (mean (height * width, C) float32, count (height * width,) int64 pixels per texel).
    """
    cov = np.asarray(coverage, bool).reshape(-1)
    uv = np.asarray(uv, np.float32).reshape(-1, 2)[cov]
    inputs = np.asarray(view_inputs, np.float32)
    inputs = inputs.reshape(-1, inputs.shape[-1])[cov].astype(np.float64)
    texel = _nearest_texel(uv, height, width)
    count = np.bincount(texel, minlength=height * width)
    mean = np.stack([np.bincount(texel, weights=inputs[:, c], minlength=height * width)
                     for c in range(inputs.shape[1])], axis=1) / np.maximum(count, 1)[:, None]
    return mean.astype(np.float32), count


@torch.no_grad()
def plain_texture(model, uv, coverage, view_inputs) -> np.ndarray:
    """(H, W, 3) float32 RGB in [0, 1] of ``model`` (a trained ``NeuralTextureModel``), one colour per texel."""
    h, w = int(model.tex_height), int(model.tex_width)
    mean, count = texel_view_inputs(uv, coverage, view_inputs, h, w)
    seen = (count > 0).reshape(h, w)
    if seen.any() and not seen.all():        # unseen texels borrow the nearest seen texel's inputs
        _, (jj, ii) = ndimage.distance_transform_edt(~seen, return_indices=True)
        mean = mean[(jj * w + ii).reshape(-1)]
    inputs = torch.from_numpy(mean)
    norm = inputs[:, :3].norm(dim=1, keepdim=True)
    inputs[:, :3] = torch.where(norm > 0, inputs[:, :3] / norm.clamp(min=1e-12), torch.tensor([0.0, 0.0, -1.0]))
    if model.mesh_layers == 2:
        inputs[:, -1] = (inputs[:, -1] > 0.5).float()
    jj, ii = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32),
                            indexing="ij")
    centres = torch.stack([(ii.reshape(-1) + 0.5) / w, (jj.reshape(-1) + 0.5) / h], dim=1)
    was_training = model.training
    model.eval()
    try:
        rgb = torch.cat([model(centres[s:s + 65536], inputs[s:s + 65536])[0] for s in range(0, h * w, 65536)])
    finally:
        model.train(was_training)
    return rgb.reshape(h, w, 3).clamp(0.0, 1.0).numpy().astype(np.float32)


def chart_mask(uvs, faces, height: int, width: int, supersample: int = 4) -> np.ndarray:
    """(H, W) bool: texels a UV triangle touches (``faces`` (F, 3) into ``uvs`` (V, 2), u right, v = row / H),
    rasterized by PIL at ``supersample`` x the atlas with outlines, so thin triangles count too."""
    from PIL import Image, ImageDraw

    s = int(supersample)
    img = Image.new("L", (width * s, height * s), 0)
    draw = ImageDraw.Draw(img)
    tri = np.asarray(uvs, np.float64)[np.asarray(faces, np.int64)] * np.float64([width * s, height * s])
    for t in tri.reshape(-1, 6).tolist():
        draw.polygon(t, fill=1, outline=1)
    fine = np.asarray(img, bool).reshape(height, s, width, s)
    return fine.any(axis=(1, 3))


def pad_gutters(rgb: np.ndarray, mask: np.ndarray, margin: int = 2) -> np.ndarray:
    """``rgb`` (H, W, C) with every texel farther than ``margin`` texels (8-neighbourhood) from ``mask`` (H, W)
    replaced by the colour of the nearest texel within it; unchanged when ``mask`` is empty."""
    keep = ndimage.binary_dilation(mask, structure=np.ones((3, 3), bool), iterations=margin) if margin else mask
    if not keep.any() or keep.all():
        return rgb.copy()
    _, (jj, ii) = ndimage.distance_transform_edt(~keep, return_indices=True)
    return rgb[jj, ii]


def plain_texture_rgb8(model, mesh, uv, coverage, view_inputs) -> np.ndarray:
    """The bundle's stored plain texture: :func:`plain_texture` with its gutters padded (:func:`pad_gutters`
    over :func:`chart_mask` of ``mesh``'s UVs), rounded to uint8 (H, W, 3) (values as displayed)."""
    rgb = plain_texture(model, uv, coverage, view_inputs)
    h, w = rgb.shape[:2]
    rgb = pad_gutters(rgb, chart_mask(mesh.uvs, mesh.faces, h, w))
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)


def plain_bundle(bundle: Bundle, rgb: np.ndarray) -> Bundle:
    """A bundle with ``bundle``'s mesh, background and origin that plays the plain texture ``rgb`` (H, W, 3)
    (no skybox pass: the sky is not a texture on the mesh)."""
    h, w = rgb.shape[:2]
    manifest = {k: v for k, v in bundle.manifest.items()
                if k in ("origin", "cull_back_faces", "core_faces", "silhouette_blend", "atlas_pages")}
    return Bundle(mesh=bundle.mesh, textures={"u_rgb": np.ascontiguousarray(rgb, np.float32)},
                  fragment_shader=plain_fragment_shader(w, h, atlas_pages(manifest)),
                  background_color=bundle.background_color,
                  manifest=manifest, vertex_shader=bundle.vertex_shader)


__all__ = ["texel_view_inputs", "plain_texture", "chart_mask", "pad_gutters", "plain_texture_rgb8",
           "plain_bundle"]
