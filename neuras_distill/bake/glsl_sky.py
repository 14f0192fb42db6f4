"""Generation of the skybox pass: a full-screen triangle whose fragment shader plays a :class:`SkyboxModel`.

Owns: :data:`SKY_VERTEX_SHADER` and :func:`generate_sky_fragment_shader`. The fragment shader reproduces the
torch forward pass of ``neural/skybox.py`` step by step:

- the pixel's ray: pixel centre ``(gl_FragCoord.x, H - gl_FragCoord.y)`` (row 0 at the top, as
  ``Cameras.pixel_directions_cam``), camera direction ``((x - cx)/fx, -(y - cy)/fy, -1)`` rotated by the
  camera-to-world rotation and normalised; the origin is ``u_sky_origin``, the camera centre *relative to the
  skybox centre* (subtracted in float64 on the CPU, so kilometre offsets cost no float32 precision);
- per layer (near to far): the exit distance ``min_k (sign(d_k) r - o_k) / d_k`` with the first minimum on
  ties, then the layer's floor where it comes first (``(h_l - n.o) / n.d`` for rays going down, stored on
  the downward face) when the layers hold a ground, the face, the clamped in-face texel coordinate and the
  atlas uv, in the same order of operations;
- the bilinear corner lookup of the index texture (``u_sky_index``) and codebook (``u_sky_codebook``) as the
  mesh shader does (``bake/glsl.py``);
- the MLP (``l1`` ReLU, opacity head sigmoid, ``l2`` on [h, d] ReLU, ``l3`` sigmoid) unrolled as mat4 * vec4
  blocks with float32-exact literals; front-to-back compositing with the outermost layer opaque.

The triangle lies on the far plane (depth 1.0); the renderer draws it after the mesh with depth test "<="
and depth writes off, so it fills exactly the pixels the mesh left at the cleared depth.
"""

from __future__ import annotations

import numpy as np

from .glsl import bilinear_feature_lines, dense_lines, glsl_float

SKY_VERTEX_SHADER = """#version 330
const vec2 CORNERS[3] = vec2[](vec2(-1.0, -1.0), vec2(3.0, -1.0), vec2(-1.0, 3.0));
void main() {
    gl_Position = vec4(CORNERS[gl_VertexID], 1.0, 1.0);   // on the far plane: depth 1.0
}
"""


def _padded_columns(w: np.ndarray, widths: list[int]) -> np.ndarray:
    """Spread the columns of ``w`` (out, sum(widths)) into 4-aligned blocks, one run per input part."""
    blocks = [(n + 3) // 4 for n in widths]
    out = np.zeros((w.shape[0], 4 * sum(blocks)), np.float32)
    src, dst = 0, 0
    for n, nb in zip(widths, blocks):
        out[:, dst:dst + n] = w[:, src:src + n]
        src += n
        dst += 4 * nb
    return out


def generate_sky_fragment_shader(skybox) -> str:
    """GLSL 400 fragment shader for a trained :class:`SkyboxModel` (see module docstring)."""
    layers = skybox.layers
    f_res = int(layers.resolution)
    h_atlas, w_atlas = layers.atlas_size
    dim = int(skybox.feature_dim)
    hidden = int(skybox.shader.hidden)
    c4 = (dim + 3) // 4
    h4 = (hidden + 3) // 4
    wts = skybox.shader.weights()
    radii = ", ".join(glsl_float(r) for r in layers.half_sizes)
    n_layers = layers.num_layers
    fr = glsl_float(float(f_res))
    ground = layers.ground
    tiny = glsl_float(1e-20)

    lines = [
        "#version 400 core",
        f"// NeuRas neural skyboxes: {n_layers} cube layers (half sizes {layers.half_sizes.round(3).tolist()}"
        + ("" if ground is None else f", floors at {ground.heights.round(3).tolist()}") + "), "
        f"{f_res}^2 texels per face, D={dim}, MLP {dim} -> {hidden} (-> opacity) -> [{hidden} + dir] -> {hidden} -> 3",
        "uniform vec3 u_sky_origin;",
        "uniform mat3 u_cam_rot;",
        "uniform vec4 u_intrinsics;",
        "uniform float u_height;",
        "uniform usampler2D u_sky_index;",
        "uniform sampler2D u_sky_codebook;",
        "out vec4 f_color;",
        f"const int LAYERS = {n_layers};",
        f"const float RADII[{n_layers}] = float[]({radii});",
        *([] if ground is None else [
            "const vec3 GROUND_N = vec3(" + ", ".join(glsl_float(float(np.float32(v))) for v in ground.normal) + ");",
            f"const float GROUND_H[{n_layers}] = float[]("
            + ", ".join(glsl_float(float(np.float32(h))) for h in ground.heights) + ");"]),
        "",
        "void main() {",
        "    vec2 px = vec2(gl_FragCoord.x, u_height - gl_FragCoord.y);",
        "    vec3 dc = vec3((px.x - u_intrinsics.z) / u_intrinsics.x, -(px.y - u_intrinsics.w) / u_intrinsics.y, -1.0);",
        "    vec3 d = normalize(u_cam_rot * dc);",
        f"    vec3 dd = mix(d, vec3({tiny}), lessThan(abs(d), vec3({tiny})));",
        "    vec3 sg = mix(vec3(1.0), vec3(-1.0), lessThan(dd, vec3(0.0)));",
        "    vec3 o = u_sky_origin;",
        *([] if ground is None else ["    float d_up = dot(dd, GROUND_N);", "    float o_up = dot(o, GROUND_N);"]),
        "    vec3 acc = vec3(0.0);",
        "    float trans = 1.0;",
        "    for (int l = 0; l < LAYERS; ++l) {",
        "        float r = RADII[l];",
        "        vec3 t = (sg * r - o) / dd;",
        "        int ax = 0;",
        "        float tm = t.x;",
        "        if (t.y < tm) { tm = t.y; ax = 1; }",
        "        if (t.z < tm) { tm = t.z; ax = 2; }",
        "        int neg = dd[ax] < 0.0 ? 1 : 0;",
        *([] if ground is None else [
            f"        if (d_up < -{tiny}) {{",
            "            float tf = (GROUND_H[l] - o_up) / d_up;",
            f"            if (tf < tm) {{ tm = tf; ax = {ground.axis}; neg = {ground.face % 2}; }}",
            "        }"]),
        "        vec3 hit = o + tm * dd;",
        "        float a = (ax == 0 ? hit.y : (ax == 1 ? hit.z : hit.x)) / r;",
        "        float b = (ax == 0 ? hit.z : (ax == 1 ? hit.x : hit.y)) / r;",
        "        int face = 2 * ax + neg;",
        f"        float x = clamp((a * 0.5 + 0.5) * {fr}, 0.5, {glsl_float(f_res - 0.5)});",
        f"        float y = clamp((b * 0.5 + 0.5) * {fr}, 0.5, {glsl_float(f_res - 0.5)});",
        "        float col = float(face % 3);",
        "        float row = float(2 * l + face / 3);",
        f"        vec2 uv = vec2((col * {fr} + x) / {glsl_float(w_atlas)}, (row * {fr} + y) / {glsl_float(h_atlas)});",
    ]
    feat = bilinear_feature_lines(lines, "uv", w_atlas, h_atlas, "u_sky_index", "u_sky_codebook", c4, "s0",
                                  "        ")
    w1, b1 = wts["l1"]
    h = dense_lines(lines, _padded_columns(w1, [dim]), b1, feat, "s1", "relu", "        ")
    wa, ba = wts["alpha"]
    alpha = dense_lines(lines, _padded_columns(wa, [hidden]), ba, h, "sa", "none", "        ")
    lines.append(f"        float alpha = l == LAYERS - 1 ? 1.0 : 1.0 / (1.0 + exp(-{alpha[0]}.x));")
    lines.append("        vec4 sd = vec4(d, 0.0);")
    w2, b2 = wts["l2"]
    h2 = dense_lines(lines, _padded_columns(w2, [hidden, 3]), b2, h + ["sd"], "s2", "relu", "        ")
    w3, b3 = wts["l3"]
    rgb = dense_lines(lines, _padded_columns(w3, [hidden]), b3, h2, "s3", "none", "        ")
    assert len(h) == h4
    lines += [
        f"        vec3 rgb = 1.0 / (1.0 + exp(-{rgb[0]}.xyz));",
        "        acc += (trans * alpha) * rgb;",
        "        trans *= 1.0 - alpha;",
        "    }",
        "    f_color = vec4(acc, 0.0);  // alpha 0: no mesh here (playback/silhouette.py)",
        "}",
        "",
    ]
    return "\n".join(lines)


__all__ = ["SKY_VERTEX_SHADER", "generate_sky_fragment_shader"]
