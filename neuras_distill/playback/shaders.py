"""The player's own GLSL, every pass of it: the vertex stage and G-buffer shaders the rasterizer and bundle playback
share, the view modes' fragment shaders, the soft-silhouette pass (full screen and in strips) and the deferred
path's visibility pass. The bundle's shaders (the neural MLP, the skyboxes) are generated in ``bake/glsl*.py``.

Shader interface (see docs/architecture.md, "Shader interface and texture binding"):
  vertex:   in vec3 in_position (world), in vec2 in_uv, in vec3 in_normal (``MeshData.vertex_normals``);
            uniform mat4 u_mvp (world -> clip); uniform float u_layer (the mesh layer being drawn, see below);
            out vec2 v_uv, out vec3 v_world (world position), out vec3 v_normal (perspective-correct interpolated).
  fragment: in vec2 v_uv, in vec3 v_world, in vec3 v_normal; uniform vec3 u_cam_pos; out vec4 f_color; one
            sampler per texture.

Two-layer meshes (``MeshData.core_faces``): the core and the shell are drawn with one draw call each, core first,
with ``u_layer`` = 0 (core) or 1 (shell). The vertex stage moves the layer's NDC depth into its own half of the
depth range, ``z' = 0.5 z + (u_layer - 0.5) w``: core NDC z in [-1, 0], shell in [0, 1], so with the depth test
"<" any core fragment wins over any shell fragment whatever their distances and the draw order (x, y and w are
untouched: coverage and perspective-correct interpolation are those of the plain projection). A single-layer
mesh is drawn with ``u_layer`` = -1: depth exactly as projected, bit-for-bit the pre-layer output. (A player that
never sets the uniform gets 0, the core range: still correct for a single-layer mesh.)

A two-layer bundle's fragment shader holds one MLP per layer behind ``#if MESH_LAYER == 1`` (shell) / ``#else``
(core): a player compiles it once per layer (:func:`shader_variant`) and draws each layer with its program.
"""

from ..bake.shader_interface import SHELL_COVERAGE

VERTEX_SHADER = """#version 330
uniform mat4 u_mvp;
uniform float u_layer;  // -1: single layer (depth as projected); 0: core (NDC z in [-1, 0]); 1: shell ([0, 1])
in vec3 in_position;
in vec2 in_uv;
in vec3 in_normal;
out vec2 v_uv;
out vec3 v_world;
out vec3 v_normal;
invariant gl_Position;  // bit-identical depth in the depth-only prepass (renderer.py) and the shading pass
void main() {
    v_uv = in_uv;
    v_world = in_position;
    v_normal = in_normal;
    gl_Position = u_mvp * vec4(in_position, 1.0);
    if (u_layer >= 0.0) {
        gl_Position.z = 0.5 * gl_Position.z + (u_layer - 0.5) * gl_Position.w;
    }
}
"""

# G-buffer fragment stage: uv, face id + 1 (0 = empty; integer attachments cannot be cleared to -1 portably
# through moderngl), view-space depth computed from the interpolated world position (exact, independent of the
# depth-buffer precision and of the per-layer depth remap). gl_PrimitiveID restarts at 0 in every draw call:
# u_face_offset (the draw call's first face) makes the id the global index into MeshData.faces.
GBUFFER_FRAGMENT_SHADER = """#version 330
uniform vec4 u_view_z;  // row 2 of the world-to-camera matrix
uniform int u_face_offset;
in vec2 v_uv;
in vec3 v_world;
in vec3 v_normal;
layout(location = 0) out vec2 f_uv;
layout(location = 1) out int f_face;
layout(location = 2) out float f_depth;
layout(location = 3) out vec4 f_normal;
void main() {
    f_uv = v_uv;
    f_face = gl_PrimitiveID + u_face_offset + 1;
    f_depth = -(dot(u_view_z.xyz, v_world) + u_view_z.w);
    f_normal = vec4(normalize(v_normal), 0.0);
}
"""




def shader_variant(source: str, mesh_layer: int) -> str:
    """The fragment shader ``source`` compiled for one mesh layer: ``#define MESH_LAYER <mesh_layer>`` right
    after its ``#version`` line. A two-layer bundle's shader holds one MLP per layer behind ``#if MESH_LAYER``
    (a branch on a uniform instead cost 40% of the frame time on llvmpipe: 55.6 vs 39.8 ms); a player builds
    one program per layer. Sources without the switch are returned unchanged."""
    if "MESH_LAYER" not in source:
        return source
    first, rest = source.split("\n", 1)
    return f"{first}\n#define MESH_LAYER {int(mesh_layer)}\n{rest}"


#: The depth-only prepass of playback (``renderer.BundleRenderer``, ``depth_prepass``): no colour output.
DEPTH_ONLY_FRAGMENT_SHADER = """#version 330
void main() {
}
"""


UV_FRAGMENT_SHADER = """#version 330 core
// view mode "uv": (u, v) as red/green under a 64 x 64 checker (chart borders show as jumps)
in vec2 v_uv;
out vec4 f_color;
void main() {
    vec2 cell = floor(v_uv * 64.0);
    float checker = mod(cell.x + cell.y, 2.0);
    f_color = vec4(vec3(v_uv, 0.35) * (0.7 + 0.3 * checker), 1.0);
}
"""

INDEX_FRAGMENT_SHADER = """#version 330 core
// view mode "index": the codebook index of the nearest texel, hashed to a colour
in vec2 v_uv;
uniform usampler2D u_index;
out vec4 f_color;
void main() {
    ivec2 size = textureSize(u_index, 0);
    ivec2 texel = clamp(ivec2(floor(v_uv * vec2(size))), ivec2(0), size - 1);
    uint k = texelFetch(u_index, texel, 0).r;
    uint h = k * 2654435761u;
    h ^= h >> 15;
    h *= 2246822519u;
    h ^= h >> 13;
    f_color = vec4(vec3(uvec3(h, h >> 8, h >> 16) & 255u) / 255.0, 1.0);
}
"""

#: A full-screen triangle (no vertex buffer: ``gl_VertexID`` 0, 1, 2).
SILHOUETTE_VERTEX_SHADER = """#version 330
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}
"""

SILHOUETTE_FRAGMENT_SHADER = """#version 330
uniform sampler2D u_scene;  // RGBA8 scene pass, LINEAR filtered: rgb, a = coverage (1 mesh or core, 0.302 shell)
out vec4 f_color;
bool one_kind(float m) {                     // a 2 x 2 block mean: all empty, all shell or all covered
    return m < 0.001 || m > 0.999 || abs(m - SHELL_COVERAGE) < 0.01;
}
void main() {
    vec2 size = vec2(textureSize(u_scene, 0));
    vec2 p = gl_FragCoord.xy / size;         // this pixel's centre
    vec2 h = 0.5 / size;                     // half a pixel: a LINEAR fetch there is the mean of a 2 x 2 block
    vec4 a = texture(u_scene, p - h);        // the block of this pixel and its left, lower, lower-left ones
    vec4 b = texture(u_scene, p + h);        // ... and its right, upper, upper-right ones
    if (one_kind(a.a) && one_kind(b.a) && abs(a.a - b.a) < 0.01) {
        f_color = vec4(texture(u_scene, p).rgb, 1.0);
    } else {                                 // an edge: the tent filter [1 2 1] x [1 2 1] / 16
        vec4 c = texture(u_scene, p + vec2(h.x, -h.y));
        vec4 d = texture(u_scene, p + vec2(-h.x, h.y));
        f_color = vec4(0.25 * (a.rgb + b.rgb + c.rgb + d.rgb), 1.0);
    }
}
""".replace("SHELL_COVERAGE", f"{SHELL_COVERAGE:.5f}")

STRIP_VERTEX_SHADER = """#version 330
in vec2 in_ndc;             // strip corners, already in normalized device coordinates
void main() {
    gl_Position = vec4(in_ndc, 0.0, 1.0);
}
"""

#: The second strip draw: copies the blended tiles back into the scene texture.
COPY_FRAGMENT_SHADER = """#version 330
uniform sampler2D u_blended;
out vec4 f_color;
void main() {
    f_color = texelFetch(u_blended, ivec2(gl_FragCoord.xy), 0);
}
"""

#: The visibility pass's fragment stage: the global face index + 1 (``u_face_offset`` as in the G-buffer's).
VISIBILITY_FRAGMENT_SHADER = """#version 330
uniform int u_face_offset;
layout(location = 0) out uint f_face;
void main() {
    f_face = uint(gl_PrimitiveID + u_face_offset + 1);
}
"""
