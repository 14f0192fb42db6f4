"""Generation of the fragment shader that plays a :class:`NeuralTextureModel` (GLSL 400 core).

Owns: :func:`generate_fragment_shader` (the neural shader) and :func:`plain_fragment_shader` (the plain-texture
baseline's). The neural shader reproduces the torch forward pass:

- bilinear corners exactly as ``neural/texture.py`` (x = u*W - 0.5, floor, clamped corners, weights
  (1-fx)(1-fy), fx(1-fy), (1-fx)fy, fx fy), blended in the order c00, c10, c01, c11;
- ``u_index`` (R16UI, H x W, CLAMP_TO_EDGE): code index per texel; the four corner indices come from one
  ``textureGather`` at the centre of the 2x2 cell (a quarter of the fetches of four texelFetch calls, which
  were the second largest cost per pixel on llvmpipe);
- ``u_codebook`` (RGBA32F, width ceil(D/4), height K): ``texelFetch(u_codebook, ivec2(c, k), 0)`` holds
  features 4c..4c+3 of code k (zero padded);
- with ``model.mesh_layers`` 2, one MLP per mesh layer behind ``#if MESH_LAYER`` (:func:`shader_variant`: a
  player compiles the source once per layer and draws each layer with its own program);
- the MLP unrolled as ``mat4 * vec4`` blocks with the weights as float literals (9 significant digits, so every
  literal is exactly the float32 weight); all-zero blocks are skipped; ReLU = max(x, 0), sigmoid = 1/(1+exp(-x));
  with ``MLPShader.output_layers`` K > 1, the last layer's K vec4s (rgb, opacity logit) are composited back to
  front with ``mix``, in ``MLPShader``'s order;
- the view direction ``normalize(v_world - u_cam_pos)`` only when the model uses it or the facing cosine
  (otherwise the shader declares no ``u_cam_pos`` at all), in a vec4 whose w is the facing cosine ``|n . d|`` when
  the model uses it (``MLPShader.use_facing``; n = ``normalize(v_normal)``, the interpolated vertex normal, as the
  G-buffer hands torch in ``GBuffer.normal``: smooth across faces, where the face normal made a fringe's fade
  faceted); with ``model.view_reflect`` the direction in that vec4 is ``reflect(dir, n)`` (``view_inputs``'s
  reflection about the same normal).

Unrolled mat4/vec4 arithmetic compiles in well under a second on Mesa llvmpipe and vectorises there.
"""

from __future__ import annotations

import math

import numpy as np

from .shader_interface import CORE_VARIANT, SHELL_COVERAGE, SHELL_VARIANT


def glsl_float(x: float) -> str:
    """A GLSL float literal that parses to exactly float32(x)."""
    v = float(np.float32(x))
    if not math.isfinite(v):
        raise ValueError(f"cannot bake a non-finite weight ({v}) into GLSL")
    s = f"{v:.9g}"
    if "." not in s and "e" not in s and "n" not in s:
        s += ".0"
    return s


def _mat4(block: np.ndarray) -> str:
    """(4 out, 4 in) block -> GLSL mat4 (column-major constructor), so that mat4 * v == block @ v."""
    return "mat4(" + ", ".join(glsl_float(block[r, c]) for c in range(4) for r in range(4)) + ")"


def _vec4(v: np.ndarray) -> str:
    return "vec4(" + ", ".join(glsl_float(x) for x in v) + ")"


def dense_lines(out: list[str], w: np.ndarray, b: np.ndarray, in_names: list[str], prefix: str, act: str,
                indent: str) -> list[str]:
    """Append ``act(W x + b)`` as vec4 blocks (mat4 * vec4 per non-zero 4x4 block of the weights) and return
    the output vec4 names ``<prefix>_<o>``. ``w`` (out, 4 * len(in_names)): its columns follow the inputs'
    4-aligned layout. ``act``: "relu" or "none"."""
    n_out = w.shape[0]
    o4 = (n_out + 3) // 4
    wp = np.zeros((4 * o4, w.shape[1]), np.float32)
    wp[:n_out] = w
    bp = np.zeros(4 * o4, np.float32)
    bp[:n_out] = b
    names = []
    for o in range(o4):
        terms = [_vec4(bp[4 * o:4 * o + 4])]
        for c, name in enumerate(in_names):
            block = wp[4 * o:4 * o + 4, 4 * c:4 * c + 4]
            if np.any(block != 0):
                terms.append(f"{_mat4(block)} * {name}")
        expr = f"\n{indent}    + ".join(terms)
        if act == "relu":
            expr = f"max({expr}, 0.0)"
        out.append(f"{indent}vec4 {prefix}_{o} = {expr};")
        names.append(f"{prefix}_{o}")
    return names


def page_lines(uv: str, pages: int, indent: str) -> list[str]:
    """GLSL lines declaring ``vp`` (``uv``'s v times the ``pages`` P) and ``layer`` (its page,
    ``min(floor(vp), P - 1)``, as a float): the v within the page is ``vp - layer``
    (``neural.texture.bilinear_corners(pages=)``). Shared by every shader that reads an atlas in pages."""
    return [f"{indent}float vp = {uv}.y * {pages}.0;",
            f"{indent}float layer = clamp(floor(vp), 0.0, {pages - 1}.0);"]


def bilinear_feature_lines(out: list[str], uv: str, tex_w: int, tex_h: int, index: str, codebook: str, c4: int,
                           prefix: str, indent: str, codes_per_row: int = 1, pages: int = 1) -> list[str]:
    """Append the GLSL of a bilinear feature lookup at ``uv`` (``texture.bilinear_corners`` arithmetic: corners
    clamped by CLAMP_TO_EDGE, blended c00, c10, c01, c11) and return the names of the ``c4`` vec4 results
    ``<prefix>_<c>``. Shared by the mesh shader and the skybox shader. With ``pages`` P > 1, ``index`` is a
    ``usampler2DArray`` of P layers of ``tex_w`` x ``tex_h`` (one page each) and ``uv``'s v is stacked
    (``texture.bilinear_corners(pages=)``): the layer is ``min(floor(v P), P - 1)``, the v within it the rest."""
    if pages > 1:
        out += [*page_lines(uv, pages, indent),
                f"{indent}vec2 xy = vec2({uv}.x, vp - layer) * vec2({tex_w}.0, {tex_h}.0) - 0.5;"]
    else:
        out.append(f"{indent}vec2 xy = {uv} * vec2({tex_w}.0, {tex_h}.0) - 0.5;")
    gather_at = f"(b0 + 1.0) / vec2({tex_w}.0, {tex_h}.0)"
    if pages > 1:
        gather_at = f"vec3({gather_at}, layer)"
    out += [
        f"{indent}vec2 b0 = floor(xy);",
        f"{indent}vec2 f = xy - b0;",
        f"{indent}vec2 g = 1.0 - f;",
        f"{indent}float w00 = g.x * g.y;",
        f"{indent}float w10 = f.x * g.y;",
        f"{indent}float w01 = g.x * f.y;",
        f"{indent}float w11 = f.x * f.y;",
        # One gather at the exact centre of the 2x2 cell (unambiguous footprint); CLAMP_TO_EDGE does the
        # border clamping. Components: x (i0, j1), y (i1, j1), z (i1, j0), w (i0, j0).
        f"{indent}uvec4 k = textureGather({index}, {gather_at});",
        f"{indent}int k00 = int(k.w);",
        f"{indent}int k10 = int(k.z);",
        f"{indent}int k01 = int(k.x);",
        f"{indent}int k11 = int(k.y);",
    ]
    names = []
    for c in range(c4):
        fetch = [codebook_fetch(codebook, c, k, c4, codes_per_row) for k in CORNER_CODES]
        out.append(f"{indent}vec4 {prefix}_{c} = w00 * {fetch[0]} + w10 * {fetch[1]} + w01 * {fetch[2]}"
                   f" + w11 * {fetch[3]};")
        names.append(f"{prefix}_{c}")
    return names


#: The GLSL names of the four corner codes :func:`bilinear_feature_lines` fetches, in blending order.
CORNER_CODES = ("k00", "k10", "k01", "k11")


def codebook_fetch(codebook: str, c: int, k: str, c4: int, codes_per_row: int = 1) -> str:
    """GLSL of the ``texelFetch`` of code ``k``'s c-th vec4 (features 4c..4c+3) from the sampler ``codebook``, a
    texture of ``codes_per_row`` n codes of ``c4`` texels per row (``bundle.wrap_codebook``): texel
    ``(c, k)`` when n is 1, else ``((k % n) * c4 + c, k / n)``."""
    n = int(codes_per_row)
    at = f"ivec2({c}, {k})" if n == 1 else f"ivec2(({k} % {n}) * {c4} + {c}, {k} / {n})"
    return f"texelFetch({codebook}, {at}, 0)"


def rewrap_codebook_fetches(source: str, codebook: str, c4: int, old: int, new: int) -> str:
    """``source`` (a shader :func:`bilinear_feature_lines` wrote, reading ``codebook`` with ``old`` codes per row)
    reading it with ``new`` codes per row instead: each of the ``4 * c4`` fetches :func:`codebook_fetch` writes
    is replaced, nothing else changes, so the result equals the shader generated with ``codes_per_row=new``
    (the web export re-wraps a codebook to its texture limit, ``export/texture_limit.py``). Raises ValueError
    when a fetch is not in ``source`` exactly once (a shader this package did not generate)."""
    if old == new:
        return source
    swaps = [(codebook_fetch(codebook, c, k, c4, old), codebook_fetch(codebook, c, k, c4, new))
             for c in range(c4) for k in CORNER_CODES]
    for before, _ in swaps:
        if source.count(before) != 1:
            raise ValueError(f"the shader reads {codebook} {source.count(before)} times as {before}, not once")
    for before, after in swaps:
        source = source.replace(before, after)
    return source


def _mlp_lines(out: list[str], shader, in_names: list[str], dim: int, c4: int, view_has_dir: bool,
               indent: str) -> str:
    """Append one ``MLPShader``'s layers reading ``in_names`` (the ``c4`` feature vec4s, then the view vec4
    ``a0_d``: (dir, facing) when ``view_has_dir``, else (facing, 0, 0, 0)) and return the GLSL expression of its
    rgb. A shader that takes no direction (a core without parallax, ``NeuralTextureModel(core_viewdir=False)``)
    gets zero weights on the direction lanes."""
    layers = shader.weights()
    w0, _ = layers[0]
    cols = np.zeros((w0.shape[0], 4 * len(in_names)), np.float32)     # features padded to 4*c4, then the view
    cols[:, :dim] = w0[:, :dim]
    at = dim
    if shader.use_viewdir:
        cols[:, 4 * c4:4 * c4 + 3] = w0[:, at:at + 3]
        at += 3
    if shader.use_facing:
        cols[:, 4 * c4 + (3 if view_has_dir else 0)] = w0[:, at]
    names = in_names
    for n, (w, b) in enumerate(layers):
        names = dense_lines(out, cols if n == 0 else w, b, names, f"a{n + 1}",
                            "none" if n == len(layers) - 1 else "relu", indent)
    if shader.output_layers == 1:
        return f"1.0 / (1.0 + exp(-{names[0]}.xyz))"
    # K colour layers, one vec4 each (rgb, opacity logit), composited back to front as MLPShader does
    layer = f"{names[0]}_l"
    out.append(f"{indent}vec3 {layer} = 1.0 / (1.0 + exp(-{names[-1]}.xyz));")
    for k in range(len(names) - 2, -1, -1):
        out.append(f"{indent}{layer} = mix({layer}, 1.0 / (1.0 + exp(-{names[k]}.xyz)), "
                   f"1.0 / (1.0 + exp(-{names[k]}.w)));")
    return layer


def generate_fragment_shader(model, codes_per_row: int = 1) -> str:
    """GLSL #version 400 core fragment shader for a trained ``NeuralTextureModel`` (see module docstring).

    The texture size is baked in as constants (``TEX_W``, ``TEX_H``; with ``model.pages`` P > 1 those of one
    page, ``u_index`` then a ``usampler2DArray`` of P layers); the codebook size is not (it comes
    with the ``u_codebook`` texture), but its layout is: ``codes_per_row`` codes per texture row
    (``bundle.wrap_codebook``; more than 1 only for codebooks taller than the largest texture side).
    """
    pages = int(getattr(model, "pages", 1))
    tex_w, tex_h, dim = int(model.tex_width), int(model.tex_height) // pages, int(model.feature_dim)
    c4 = (dim + 3) // 4
    use_dir = any(bool(s.use_viewdir) for s in model.shaders)
    use_facing = bool(model.use_facing)
    use_reflect = bool(model.view_reflect)     # only ever set with a direction input
    layers = model.shader.weights()      # the core's (a shell's shader may be wider: ``shell_hidden``)

    out: list[str] = [
        "#version 400 core",
        "// NeuRas neural texture shader: " + (f"{pages} pages of " if pages > 1 else "")
        + f"{tex_w}x{tex_h} atlas, D={dim}, MLP "
        + " -> ".join(str(w.shape[1]) for w, _ in layers) + " -> 3"
        + (f" ({model.shader.output_layers} layers composited)" if model.shader.output_layers > 1 else "")
        + (", view-dependent" if use_dir else "") + (" (reflected direction)" if use_reflect else "")
        + (", facing" if use_facing else "")
        + (f", one MLP per mesh layer (the shell's {model.shaders[-1].hidden} wide)" if model.mesh_layers == 2 else ""),
        "in vec2 v_uv;",
    ]
    if use_dir or use_facing:
        out += ["in vec3 v_world;", "uniform vec3 u_cam_pos;"]
    if use_facing or use_reflect:
        out.append("in vec3 v_normal;")
    if model.mesh_layers == 2:
        out += ["#ifndef MESH_LAYER",
                f"#define MESH_LAYER {CORE_VARIANT}  // the shell's program: shader_variant(source, 1)",
                "#endif"]
    out += [
        "uniform usampler2DArray u_index;" if pages > 1 else "uniform usampler2D u_index;",
        "uniform sampler2D u_codebook;",
        "out vec4 f_color;",
        "",
        "void main() {",
    ]
    in_names = bilinear_feature_lines(out, "v_uv", tex_w, tex_h, "u_index", "u_codebook", c4, "a0", "    ",
                                      codes_per_row, pages)
    if use_facing or use_reflect:
        shown = "reflect(dir, nrm)" if use_reflect else "dir"
        out += ["    vec3 dir = normalize(v_world - u_cam_pos);",
                "    vec3 nrm = normalize(v_normal);"]
        if use_facing:
            out += ["    float facing = abs(dot(nrm, dir));",
                    "    vec4 a0_d = " + (f"vec4({shown}, facing);" if use_dir else "vec4(facing, 0.0, 0.0, 0.0);")]
        else:
            out.append(f"    vec4 a0_d = vec4({shown}, 0.0);")
        in_names.append("a0_d")
    elif use_dir:
        out.append("    vec4 a0_d = vec4(normalize(v_world - u_cam_pos), 0.0);")
        in_names.append("a0_d")

    if model.mesh_layers == 1:
        rgb = _mlp_lines(out, model.shader, in_names, dim, c4, use_dir, "    ")
        out += [f"    vec3 rgb = {rgb};", "    f_color = vec4(rgb, 1.0);"]
    else:       # a two-layer mesh: one program per layer, MESH_LAYER picks the shader at compile time
        out.append("    vec3 rgb;")
        layers = ((f"#if MESH_LAYER == {SHELL_VARIANT}", model.shaders[1], SHELL_COVERAGE),
                  ("#else", model.shaders[0], 1.0))
        for directive, shader, coverage in layers:   # alpha: the layer's coverage (playback/silhouette.py)
            out.append(directive)
            rgb = _mlp_lines(out, shader, in_names, dim, c4, use_dir, "    ")
            out += [f"    rgb = {rgb};", f"    f_color = vec4(rgb, {coverage!r});"]
        out.append("#endif")
    out += [
        "}",
        "",
    ]
    return "\n".join(out)


#: The lines :func:`to_glsl_es` puts after ``#version 300 es``: WebGL2 fragment shaders have no default float
#: precision and no default for the integer samplers; highp everywhere is what the desktop computes in.
GLSL_ES_PRECISION = ("precision highp float;", "precision highp int;", "precision highp sampler2D;",
                     "precision highp usampler2D;")

#: GLSL ES 3.00 has no ``textureGather`` (ES 3.10 has): :func:`to_glsl_es` renames the calls to this function,
#: defined right after the precision lines, which fetches the same four texels (CLAMP_TO_EDGE, component order
#: x (i0, j1), y (i1, j1), z (i1, j0), w (i0, j0)) with ``texelFetch``; integer-valued, so bit-exact.
GLSL_ES_GATHER = """uvec4 neurasGather(usampler2D s, vec2 p) {  // textureGather (GLSL ES 3.00 has none): 4 texelFetch
    ivec2 size = textureSize(s, 0);
    ivec2 i0 = ivec2(floor(p * vec2(size) - 0.5));
    ivec2 lo = clamp(i0, ivec2(0), size - 1);
    ivec2 hi = clamp(i0 + 1, ivec2(0), size - 1);
    return uvec4(texelFetch(s, ivec2(lo.x, hi.y), 0).r, texelFetch(s, hi, 0).r,
                 texelFetch(s, ivec2(hi.x, lo.y), 0).r, texelFetch(s, lo, 0).r);
}"""

#: The same for a texture array (atlas pages): :func:`to_glsl_es` adds it, and the array sampler's precision,
#: when the source declares a ``usampler2DArray``. ``p.z`` is the layer (integer-valued).
GLSL_ES_GATHER_ARRAY = """uvec4 neurasGather(usampler2DArray s, vec3 p) {  // the same on one layer of an array
    ivec2 size = textureSize(s, 0).xy;
    int layer = int(p.z);
    ivec2 i0 = ivec2(floor(p.xy * vec2(size) - 0.5));
    ivec2 lo = clamp(i0, ivec2(0), size - 1);
    ivec2 hi = clamp(i0 + 1, ivec2(0), size - 1);
    return uvec4(texelFetch(s, ivec3(lo.x, hi.y, layer), 0).r, texelFetch(s, ivec3(hi, layer), 0).r,
                 texelFetch(s, ivec3(hi.x, lo.y, layer), 0).r, texelFetch(s, ivec3(lo, layer), 0).r);
}"""


def to_glsl_es(source: str) -> str:
    """The desktop GLSL ``source`` (any shader this package generates or ships: ``#version 330`` / ``400 core``)
    rewritten as GLSL ES 3.00 for WebGL2 (``export/web.py``). The rewrite, and all of it:

    1. the ``#version`` line becomes ``#version 300 es`` followed by :data:`GLSL_ES_PRECISION`;
    2. where the source calls ``textureGather(``, the calls become ``neurasGather(`` and :data:`GLSL_ES_GATHER`
       follows the precision lines (the only desktop function the generated shaders use that ES 3.00 lacks);
       a source with a ``usampler2DArray`` (atlas pages) gets that sampler's precision line and
       :data:`GLSL_ES_GATHER_ARRAY` instead.

    Everything else is kept byte for byte (tests/test_web.py undoes the rewrite and compares). Deterministic;
    raises ValueError when the first line is not a ``#version`` directive.
    """
    first, sep, rest = source.partition("\n")
    if not first.startswith("#version"):
        raise ValueError(f"a GLSL source must start with its #version line, got {first[:40]!r}")
    head = ["#version 300 es", *GLSL_ES_PRECISION]
    arrays = "usampler2DArray" in rest
    if arrays:
        head.append("precision highp usampler2DArray;")
    if "textureGather(" in rest:
        rest = rest.replace("textureGather(", "neurasGather(")
        head.append(GLSL_ES_GATHER_ARRAY if arrays else GLSL_ES_GATHER)
    return "\n".join(head) + sep + rest


def plain_fragment_shader(width: int, height: int, pages: int = 1) -> str:
    """GLSL 330 fragment shader playing an RGB float texture ``u_rgb`` (H x W x 3, texelFetch only) with the
    bilinear-corner arithmetic of ``neural.texture.bilinear_corners``; with ``pages`` P > 1 (H = P * W) a
    ``sampler2DArray`` of P layers of W x W, v stacked as there."""
    if pages > 1:
        side = height // pages
        lookup = [*page_lines("v_uv", pages, "    "),
                  f"    vec2 xy = vec2(v_uv.x, vp - layer) * vec2({width}.0, {side}.0) - 0.5;"]
        sampler, height, fetch = "sampler2DArray", side, "texelFetch(u_rgb, ivec3({}, int(layer)), 0).rgb"
    else:
        lookup = [f"    vec2 xy = v_uv * vec2({width}.0, {height}.0) - 0.5;"]
        sampler, fetch = "sampler2D", "texelFetch(u_rgb, {}, 0).rgb"
    return "\n".join([
        "#version 330 core",
        "// plain RGB texture, " + (f"{pages} pages of " if pages > 1 else "")
        + f"{width}x{height}, bilinear (the baseline of the neural shader)",
        "in vec2 v_uv;",
        f"uniform {sampler} u_rgb;",
        "out vec4 f_color;",
        "void main() {",
        *lookup,
        "    vec2 b0 = floor(xy);",
        "    vec2 f = xy - b0;",
        "    vec2 g = 1.0 - f;",
        f"    ivec2 hi = ivec2({width - 1}, {height - 1});",
        "    ivec2 c0 = clamp(ivec2(b0), ivec2(0), hi);",
        "    ivec2 c1 = clamp(ivec2(b0) + 1, ivec2(0), hi);",
        f"    vec3 rgb = g.x * g.y * {fetch.format('c0')}"
        f" + f.x * g.y * {fetch.format('ivec2(c1.x, c0.y)')}"
        f" + g.x * f.y * {fetch.format('ivec2(c0.x, c1.y)')}"
        f" + f.x * f.y * {fetch.format('c1')};",
        "    f_color = vec4(rgb, 1.0);",
        "}",
        "",
    ])
