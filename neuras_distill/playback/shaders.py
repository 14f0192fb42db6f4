"""GLSL sources shared by the G-buffer rasterizer and bundle playback (this module owns the vertex stage).

Shader interface (see docs/architecture.md):
  vertex:   in vec3 in_position (world), in vec2 in_uv; uniform mat4 u_mvp (world -> clip);
            out vec2 v_uv, out vec3 v_world (world position, perspective-correct interpolated).
  fragment: in vec2 v_uv, in vec3 v_world; uniform vec3 u_cam_pos; out vec4 f_color; one sampler per texture.
"""

VERTEX_SHADER = """#version 330
uniform mat4 u_mvp;
in vec3 in_position;
in vec2 in_uv;
out vec2 v_uv;
out vec3 v_world;
void main() {
    v_uv = in_uv;
    v_world = in_position;
    gl_Position = u_mvp * vec4(in_position, 1.0);
}
"""

# G-buffer fragment stage: uv, face id + 1 (0 = empty; integer attachments cannot be cleared to -1 portably
# through moderngl), view-space depth computed from the interpolated world position (exact, independent of the
# depth-buffer precision).
GBUFFER_FRAGMENT_SHADER = """#version 330
uniform vec4 u_view_z;  // row 2 of the world-to-camera matrix
in vec2 v_uv;
in vec3 v_world;
layout(location = 0) out vec2 f_uv;
layout(location = 1) out int f_face;
layout(location = 2) out float f_depth;
void main() {
    f_uv = v_uv;
    f_face = gl_PrimitiveID + 1;
    f_depth = -(dot(u_view_z.xyz, v_world) + u_view_z.w);
}
"""
