"""The texture limit of the exports: every texture the web and glTF exports write is at most ``limit`` texels a side.

Owns: :data:`DEFAULT_MAX_TEXTURE_SIZE`, :func:`checked_limit`, :func:`check_side`, :func:`fit_codebook` and
:func:`fit_bundle_textures`. The default, 4096, is a side WebGL2 implementations hold in practice (the WebGL2
specification promises only 2048; Chromium's SwiftShader gives 8192, Mesa llvmpipe and desktop GPUs 16384 or
more); ``neuras-distill export --max-texture-size N`` sets another for a known target. The bundle itself is not
changed: the native player binds its textures as they are (a codebook up to ``bundle.CODEBOOK_MAX_ROWS`` rows),
the exports fit them here:

- a codebook (``u_codebook``, ``u_sky_codebook``: K codes of C4 RGBA32F texels, ``bundle.wrap_codebook`` with n
  codes per row) is wrapped again with the fewest codes per row that keep it at most ``limit`` rows
  (``bundle.codes_per_row``), and its shader's fetches are rewritten to match
  (``glsl.rewrap_codebook_fetches``: the shader the bake would have generated with that wrap); the default
  demo's 34,403 codes of 2 texels: 3 per row as baked (6 x 11468), 9 per row exported (18 x 3823);
- any other texture (the index maps ``u_index``, ``u_sky_index``; a plain bundle's ``u_rgb``; the glTF's
  plain-texture images) must already fit, one atlas page at a time for a texture in pages
  (``bundle.PAGED_TEXTURES``): re-cutting an atlas means unwrapping the mesh again, a bake's job.

A texture that cannot fit raises :class:`~neuras_distill.errors.BadInputError` naming the texture, its size, the
limit and the setting that fixes it; the exports check before they write anything.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import BadInputError

#: The exports' texture side limit unless ``--max-texture-size`` says otherwise.
DEFAULT_MAX_TEXTURE_SIZE = 4096

#: What makes each texture smaller at bake time (the first half of the error line's fix).
BAKE_FIX = {
    "u_index": "bake it with texture.page_size {limit} or less",
    "u_rgb": "bake it with texture.page_size {limit} or less",
    "plain_rgb": "bake it with texture.page_size {limit} or less",
    "u_sky_index": "bake it with a smaller skybox.resolution or fewer skybox.layers",
    "u_codebook": "bake it with fewer texture.num_codes",
    "u_sky_codebook": "bake it with fewer skybox.num_codes",
}


def checked_limit(limit) -> int:
    """``limit`` as an int, or BadInputError unless it is a whole number of texels of at least 1."""
    if isinstance(limit, bool) or not isinstance(limit, (int, np.integer)) or limit < 1:
        raise BadInputError(f"--max-texture-size must be a positive whole number of texels, got {limit!r}")
    return int(limit)


def _too_large(name: str, size: str, limit: int, needed: int) -> BadInputError:
    fix = BAKE_FIX.get(name, "bake it smaller").format(limit=limit)
    return BadInputError(f"texture {name} is {size}, above the export's limit of {limit} texels per side: {fix}, "
                         f"or export with --max-texture-size {needed} for a target that holds it")


def check_side(name: str, width: int, height: int, limit: int, pages: int = 1, needed: int | None = None) -> None:
    """BadInputError unless a ``width`` x ``height`` texture (with ``pages`` P > 1: P pages of ``width`` x
    ``height / P``, a texture array) has both sides at most ``limit``. ``needed``: the limit the message suggests
    (default this texture's largest side)."""
    h = int(height) // max(1, int(pages))
    if max(int(width), h) > limit:
        size = f"{width}x{h}" + (f" per page ({pages} pages)" if pages > 1 else "")
        raise _too_large(name, size, limit, needed or max(int(width), h))


def smallest_limit(num_codes: int, c4: int) -> int:
    """The smallest side s of a square that holds ``num_codes`` codes of ``c4`` texels wrapped into rows:
    ``s * floor(s / c4) >= num_codes``."""
    s = max(int(c4), math.isqrt(max(0, int(num_codes) * int(c4) - 1)) + 1)
    while s * (s // c4) < num_codes:
        s += 1
    return s


def fit_codebook(name: str, texture: np.ndarray, num_codes: int, per_row: int, limit: int,
                 needed: int | None = None) -> tuple[np.ndarray, int]:
    """(texture, codes per row) of the codebook ``texture`` (float32 (rows, per_row * C4, 4) holding
    ``num_codes`` K codes, ``bundle.wrap_codebook``) within ``limit`` texels a side: unchanged when it fits, else
    wrapped again with ``bundle.codes_per_row(K, limit)`` codes per row. BadInputError when no wrap fits
    (``per_row * C4 > limit``), suggesting ``needed`` (default :func:`smallest_limit`)."""
    from ..bake.bundle import codes_per_row, wrap_codebook

    rows, width = texture.shape[:2]
    if max(rows, width) <= limit:
        return texture, per_row
    c4 = width // per_row
    new = codes_per_row(num_codes, limit)
    if new * c4 > limit:
        raise _too_large(name, f"{width}x{rows} ({num_codes} codes of {c4} texels; at most {limit * (limit // c4)} "
                         f"fit {limit}x{limit})", limit, needed or smallest_limit(num_codes, c4))
    codes = np.ascontiguousarray(texture, np.float32).reshape(rows * per_row, c4, 4)[:num_codes]
    return wrap_codebook(codes, new), new


def fit_bundle_textures(bundle, limit: int) -> tuple[dict, str, str | None]:
    """(textures, fragment shader, sky fragment shader) of ``bundle`` with every texture within ``limit`` texels
    a side (module docstring): ``textures`` {uniform name: array} as ``Bundle.textures``, the codebooks wrapped
    again where needed and the shaders reading them rewritten to match. BadInputError naming the first texture
    (in name order) that cannot fit, with the smallest ``--max-texture-size`` that fits them all, or a shader
    that does not read its codebook as the bake writes it."""
    from ..bake.bundle import PAGED_TEXTURES, atlas_pages
    from ..bake.glsl import rewrap_codebook_fetches

    manifest = bundle.manifest or {}
    shaders = {"u_codebook": bundle.fragment_shader, "u_sky_codebook": bundle.sky_fragment_shader}
    per_rows = {"u_codebook": int(manifest.get("codes_per_row", 1)), "u_sky_codebook": 1}   # the sky: never wrapped
    pages = atlas_pages(manifest)
    items = []                                       # (name, array, (K, per_row) of a codebook or None, side needed)
    for name, arr in sorted(bundle.textures.items()):
        arr = np.asarray(arr)
        if name in shaders and arr.ndim == 3:
            per_row = per_rows[name]
            k = int(manifest.get("num_codes", arr.shape[0] * per_row)) if name == "u_codebook" else int(arr.shape[0])
            items.append((name, arr, (k, per_row), min(max(arr.shape[:2]), smallest_limit(k, arr.shape[1] // per_row))))
        else:
            items.append((name, arr, None, max(arr.shape[1], arr.shape[0] // (pages if name in PAGED_TEXTURES else 1))))
    needed = max((item[3] for item in items), default=1)
    textures = {}
    for name, arr, codebook, _ in items:
        if codebook is not None:
            num_codes, per_row = codebook
            fitted, new = fit_codebook(name, arr, num_codes, per_row, limit, needed)
            if new != per_row:
                try:
                    shaders[name] = rewrap_codebook_fetches(shaders[name], name, arr.shape[1] // per_row, per_row, new)
                except ValueError as exc:
                    raise BadInputError(f"texture {name} needs wrapping to fit {limit} texels per side, but the "
                                        f"bundle's shader does not read it as the bake writes it ({exc}); bake the "
                                        "bundle again") from None
            textures[name] = fitted
        else:
            check_side(name, arr.shape[1], arr.shape[0], limit, pages if name in PAGED_TEXTURES else 1, needed)
            textures[name] = arr
    return textures, shaders["u_codebook"], shaders["u_sky_codebook"]


__all__ = ["DEFAULT_MAX_TEXTURE_SIZE", "check_side", "checked_limit", "fit_bundle_textures", "fit_codebook",
           "smallest_limit"]
