"""What the window player can show of a bundle besides its neural shader (keys 1-4 in ``playback/window.py``).

Owns: :data:`VIEW_MODES`, :func:`mode_bundle` and the two diagnostic fragment shaders. Each mode is a
``Bundle`` with the same mesh, draw calls, origin, background and skybox pass and another fragment shader, so
``BundleRenderer`` plays all of them the same way:

* ``neural``: the bundle itself (what every other player plays).
* ``plain``: the plain baked RGB texture (``bake/plain_texture.py``; bundles store it as
  plain_rgb.png), bilinear, with the skybox pass kept (the sky is not on the mesh).
* ``uv``: the UV atlas: red/green = (u, v), overlaid with a 64 x 64 checker, so chart borders show as jumps of
  colour or of the checker's phase, and texel density as the checker's size on screen.
* ``index``: the codebook index each texel holds (``u_index``, nearest texel), as a hashed colour: texels
  sharing a code share a colour, so the patches the vector quantiser makes are what you see.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import BadInputError
from .shaders import INDEX_FRAGMENT_SHADER, UV_FRAGMENT_SHADER

#: Mode name -> one-line description (window title, ``view --mode`` help), in key order (1, 2, 3, 4).
VIEW_MODES = {
    "neural": "the neural shader (the bundle as every player plays it)",
    "plain": "the plain baked RGB texture (what the neural shader is measured against)",
    "uv": "UV charts: (u, v) as red/green under a 64 x 64 checker",
    "index": "the codebook index per texel, as a hashed colour",
}

def index_fragment_shader(pages: int = 1) -> str:
    """``shaders.INDEX_FRAGMENT_SHADER``, or for an atlas in ``pages`` P > 1 (``u_index`` a texture array, v stacked
    as in ``neural.texture.bilinear_corners``) the same on the uv's page."""
    if pages <= 1:
        return INDEX_FRAGMENT_SHADER
    from ..bake.glsl import page_lines  # noqa: PLC0415

    return (INDEX_FRAGMENT_SHADER
            .replace("uniform usampler2D u_index;", "uniform usampler2DArray u_index;")
            .replace("    ivec2 size = textureSize(u_index, 0);\n",
                     "\n".join(["    ivec2 size = textureSize(u_index, 0).xy;",
                                *page_lines("v_uv", pages, "    "), ""]))
            .replace("floor(v_uv * vec2(size))", "floor(vec2(v_uv.x, vp - layer) * vec2(size))")
            .replace("texelFetch(u_index, texel, 0)", "texelFetch(u_index, ivec3(texel, int(layer)), 0)"))


def mode_bundle(bundle, mode: str):
    """The ``Bundle`` that plays ``mode`` (a :data:`VIEW_MODES` key) of ``bundle``; BadInputError for an
    unknown mode or ``plain`` on a bundle without a plain texture."""
    if mode not in VIEW_MODES:
        raise BadInputError(f"unknown view mode {mode!r}; known modes: {', '.join(VIEW_MODES)}")
    if mode == "neural":
        return bundle
    if mode == "plain":
        from ..bake.plain_texture import plain_bundle  # noqa: PLC0415 (torch; lazy)

        if bundle.plain_rgb is None:
            raise BadInputError("this bundle has no plain texture (plain_rgb.png): re-run the pipeline to bake "
                                "one (bundles baked by older versions have none)")
        plain = plain_bundle(bundle, bundle.plain_rgb.astype(np.float32) / 255.0)
        if not bundle.has_skybox:
            return plain
        sky_textures = {k: v for k, v in bundle.textures.items() if k.startswith("u_sky_")}
        manifest = dict(plain.manifest, skybox=bundle.manifest["skybox"])
        return replace(plain, textures={**plain.textures, **sky_textures}, manifest=manifest,
                       sky_fragment_shader=bundle.sky_fragment_shader)
    from ..bake.bundle import atlas_pages  # noqa: PLC0415

    shader = UV_FRAGMENT_SHADER if mode == "uv" else index_fragment_shader(atlas_pages(bundle.manifest))
    return replace(bundle, fragment_shader=shader)


__all__ = ["VIEW_MODES", "mode_bundle", "index_fragment_shader"]
