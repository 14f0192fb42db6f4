"""GLSL sources shared by the G-buffer rasterizer and bundle playback (this module owns the vertex stage).

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
