"""Deferred playback for rasterizing GPUs: a visibility buffer, then the bundle's shaders in compute passes.

Why: on NVIDIA's data-centre GPUs (H100, H200) the raster pipeline's fixed-function back end is a small part of
the chip, while compute runs on all of it. Measured on an H100 (GL timer queries, the demo bundle at
1920 x 1080, its mesh covering 20% of the frame): clearing an RGBA8 colour and a depth
buffer 0.26 ms; the mesh pass with the neural shader 0.69 ms (0.41 with a constant-colour shader, 0.58 with
the feature lookups and no MLP); the same shading as a compute shader 0.022 ms, bit-identical; the
soft-silhouette pass 0.32 ms as a fragment pass over the mesh's screen box, 0.018 ms as a compute pass over the
whole frame; the street's skybox pass 0.86 ms; a G-buffer of two RGBA32F targets (uv, world position) 1.71 ms.
So the raster pipeline here should write as few bytes as it can and shade nothing.

A frame (:meth:`DeferredFrame.draw`):

1. **visibility pass** (raster): the mesh with ``shaders.VERTEX_SHADER`` (same depth test, culling and two-layer
   depth ranges as the forward path, ``rasterize.draw_mesh``) writing only ``face + 1`` (R32UI) and depth; only
   the depth is cleared (a pixel with depth 1 has no face; clearing the ids too cost 0.15 ms more);
2. **shading pass** (compute, 16 x 8 invocations a group): per pixel, the face's three vertices from storage
   buffers; the ray through the pixel centre (from the rows of the mvp, so exactly the rasterizer's pixel
   convention) meets the face's plane at the barycentrics that perspective-correct interpolation gives; uv,
   position (bundle frame) and vertex normal interpolated with them; then the bundle's own fragment shader,
   its ``main`` turned into a function (:func:`compute_shading_source`; a two-layer bundle's core and shell
   variants as two functions, chosen by the face's layer); RGBA8 result, alpha 1. Pixels without a face get
   the background colour with alpha 0, or, with skyboxes, a second dispatch of the sky shader the same way;
3. **silhouette pass** (compute), when the bundle has one: ``shaders.SILHOUETTE_FRAGMENT_SHADER``'s arithmetic
   over the whole frame, into a second image (every pixel it does not blend passes through).

The picture is the forward path's up to the barycentrics' rounding (the rasterizer interpolates in its own
fixed-point arithmetic): tests/test_deferred.py compares the two on llvmpipe. On software GL the forward path is
faster (llvmpipe runs compute shaders on fewer threads: the demo's shading 25 ms as fragments, 50 ms as compute)
and stays the default there (``BundleRenderer(shading=)``).

Owns: :func:`compute_shading_source` (any fragment shader of the playback interface as a compute pass),
:func:`compute_supported`, :class:`DeferredFrame`. Frames: vertices and the eye in the bundle's frame (the
renderer shifts cameras by the bundle's origin), image rows bottom-up (GL's window convention).
"""

from __future__ import annotations

import re

import numpy as np

from ..bake.shader_interface import CORE_VARIANT, SHELL_VARIANT
from ..errors import BadInputError
from .rasterize import draw_mesh, set_raster_state
from .shaders import SILHOUETTE_FRAGMENT_SHADER, VERTEX_SHADER, VISIBILITY_FRAGMENT_SHADER

#: Compute work group: 16 x 8 pixels (measured on the H100 with the demo's shader: 8 x 8 0.027 ms, 16 x 8
#: 0.022 ms, 32 x 4 0.023 ms).
GROUP = (16, 8)

#: Texture units of the passes' own inputs (the face ids, the scene for the silhouette pass), above the
#: bundle's textures (units 0, 1, ... in name order; a bundle has at most five).
DEPTH_UNIT, FACE_UNIT, SCENE_UNIT = 13, 14, 15

#: The varyings a playback fragment shader may read (``shaders.py``'s interface); the compute pass sets them.
_VARYINGS = {"in vec2 v_uv;": "vec2 v_uv;", "in vec3 v_world;": "vec3 v_world;", "in vec3 v_normal;": "vec3 v_normal;"}

_PRELUDE = f"""#version 430
layout(local_size_x = {GROUP[0]}, local_size_y = {GROUP[1]}) in;
uniform ivec2 neuras_size;                     // the frame in pixels
uniform sampler2D neuras_depth;                // the visibility pass's depth: 1 where no face was drawn
uniform usampler2D neuras_face;                // and face + 1 where one was (not cleared: read under depth < 1)
layout(rgba8) uniform writeonly image2D neuras_out;
vec4 neurasFragCoord;                          // gl_FragCoord of the fragment stage: the pixel centre
vec4 f_color;
"""

_MESH_MAIN = """
layout(std430, binding = 0) readonly buffer NeurasFaces { uint neuras_faces[]; };        // 3 vertex indices a face
layout(std430, binding = 1) readonly buffer NeurasVertices { float neuras_vertices[]; };  // 8 floats a vertex
uniform vec3 neuras_eye;                       // the camera centre (bundle frame)
uniform vec3 neuras_row_x;                     // rows 0, 1, 3 of the mvp's first three columns
uniform vec3 neuras_row_y;
uniform vec3 neuras_row_w;
uniform vec4 neuras_background;                // written (rgb, alpha 0) where no face is, unless a sky follows
uniform int neuras_write_background;
uniform int neuras_core_faces;                 // faces below are the core's (two-layer bundles)

vec3 neuras_vertex(uint v, int at) {
    uint o = 8u * v + uint(at);
    return vec3(neuras_vertices[o], neuras_vertices[o + 1u], neuras_vertices[o + 2u]);
}

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= neuras_size.x || p.y >= neuras_size.y) return;
    uint id = texelFetch(neuras_depth, p, 0).r < 1.0 ? texelFetch(neuras_face, p, 0).r : 0u;
    if (id == 0u) {
        if (neuras_write_background != 0) imageStore(neuras_out, p, neuras_background);
        return;
    }
    uint face = id - 1u;
    uint i0 = neuras_faces[3u * face], i1 = neuras_faces[3u * face + 1u], i2 = neuras_faces[3u * face + 2u];
    vec3 p0 = neuras_vertex(i0, 0), p1 = neuras_vertex(i1, 0), p2 = neuras_vertex(i2, 0);
    neurasFragCoord = vec4(vec2(p) + 0.5, 0.0, 1.0);
    vec2 ndc = 2.0 * neurasFragCoord.xy / vec2(neuras_size) - 1.0;
    vec3 d = cross(neuras_row_x - ndc.x * neuras_row_w, neuras_row_y - ndc.y * neuras_row_w);
    // the ray through the pixel centre meets the face's plane (Moller-Trumbore): barycentrics (1 - b, b.x, b.y)
    vec3 e1 = p1 - p0, e2 = p2 - p0;
    vec3 pv = cross(d, e2);
    float det = dot(e1, pv);
    vec2 b = vec2(0.0);
    if (det != 0.0) {
        vec3 tv = neuras_eye - p0;
        vec3 qv = cross(tv, e1);
        b = vec2(dot(tv, pv), dot(d, qv)) / det;
    }
    float b0 = 1.0 - b.x - b.y;
    v_world = b0 * p0 + b.x * p1 + b.y * p2;
    v_uv = b0 * vec2(neuras_vertices[8u * i0 + 3u], neuras_vertices[8u * i0 + 4u])
         + b.x * vec2(neuras_vertices[8u * i1 + 3u], neuras_vertices[8u * i1 + 4u])
         + b.y * vec2(neuras_vertices[8u * i2 + 3u], neuras_vertices[8u * i2 + 4u]);
    v_normal = b0 * neuras_vertex(i0, 5) + b.x * neuras_vertex(i1, 5) + b.y * neuras_vertex(i2, 5);
    SHADE
    imageStore(neuras_out, p, f_color);
}
"""

_SKY_MAIN = """
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= neuras_size.x || p.y >= neuras_size.y) return;
    if (texelFetch(neuras_depth, p, 0).r < 1.0) return;
    neurasFragCoord = vec4(vec2(p) + 0.5, 1.0, 1.0);
    neuras_shade();
    imageStore(neuras_out, p, f_color);
}
"""

_PASS_MAIN = """
void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= neuras_size.x || p.y >= neuras_size.y) return;
    neurasFragCoord = vec4(vec2(p) + 0.5, 0.0, 1.0);
    neuras_shade();
    imageStore(neuras_out, p, f_color);
}
"""


def _split_fragment_shader(source: str) -> tuple[list[str], list[str]]:
    """(declarations, main's body up to its closing brace) of a playback fragment shader, with the declarations
    made fit for a compute shader: no ``#version``, varyings and ``out vec4 f_color`` dropped (the prelude
    declares them as globals), ``gl_FragCoord`` renamed. ValueError for a shader outside the interface."""
    lines = source.replace("gl_FragCoord", "neurasFragCoord").split("\n")
    try:
        start = next(i for i, ln in enumerate(lines) if re.match(r"\s*void\s+main\s*\(\s*\)\s*\{\s*$", ln))
    except StopIteration:
        raise ValueError("the fragment shader has no 'void main() {' line") from None
    head = []
    for ln in lines[:start]:
        s = ln.strip()
        if s.startswith("#version") or s in _VARYINGS or s == "out vec4 f_color;":
            continue
        if re.match(r"(layout\s*\(.*\)\s*)?(in|out)\s", s):
            raise ValueError(f"the fragment shader declares {s!r}, outside the playback interface")
        head.append(ln)
    body = lines[start + 1:]
    while body and not body[-1].strip():
        body.pop()
    return head, body


def compute_shading_source(fragment_shader: str, kind: str = "mesh", two_layers: bool = False) -> str:
    """A compute shader (GLSL 430, :data:`GROUP` invocations a group) running ``fragment_shader``'s ``main`` once
    per pixel of ``neuras_out`` (an RGBA8 image).

    ``kind`` "mesh": the pixel's varyings come from the visibility buffer (see the module docstring) and pixels
    without a face get ``neuras_background``; with ``two_layers``, the shader is compiled twice into the source
    (``MESH_LAYER`` core then shell, as ``shaders.shader_variant`` does for a program per layer) and the face's
    index picks one (below ``neuras_core_faces``: the core). "sky": only the pixels without a face. "pass": every
    pixel, for screen-space passes that read ``neurasFragCoord`` (the silhouette pass).
    Raises ValueError when the shader is not of the playback interface (other inputs or outputs, no main)."""
    head, body = _split_fragment_shader(fragment_shader)
    out = [_PRELUDE]
    if kind == "mesh":
        out.append("vec2 v_uv;\nvec3 v_world;\nvec3 v_normal;")
        if two_layers:
            out.append(f"#define MESH_LAYER {CORE_VARIANT}")
        out += head
        if two_layers:
            out += ["void neuras_shade_core() {", *body,
                    "#undef MESH_LAYER", f"#define MESH_LAYER {SHELL_VARIANT}",
                    "void neuras_shade_shell() {", *body]
            shade = "if (int(face) < neuras_core_faces) neuras_shade_core(); else neuras_shade_shell();"
        else:
            out += ["void neuras_shade() {", *body]
            shade = "neuras_shade();"
        out.append(_MESH_MAIN.replace("SHADE", shade))
    elif kind in ("sky", "pass"):
        out += head
        out += ["void neuras_shade() {", *body, _SKY_MAIN if kind == "sky" else _PASS_MAIN]
    else:
        raise ValueError(f"kind must be 'mesh', 'sky' or 'pass', got {kind!r}")
    return "\n".join(out)


_TRIVIAL_COMPUTE = "#version 430\nlayout(local_size_x = 1) in;\nvoid main() {}\n"


def compute_supported(ctx) -> bool:
    """Whether ``ctx`` compiles compute shaders (GL 4.3, or the NVIDIA driver's 3.3 contexts, which do): one
    trivial compute shader compiled and released (a millisecond; asked once per renderer)."""
    try:
        ctx.compute_shader(_TRIVIAL_COMPUTE).release()
    except Exception:                       # noqa: BLE001 - moderngl.Error, or no compute_shader at all
        return False
    return True


def _set(program, name: str, value) -> None:
    if name in program:
        program[name].value = value


class DeferredFrame:
    """The GL objects of deferred playback for one bundle (built by ``BundleRenderer(shading="deferred")``).

    Args:
        ctx: the renderer's moderngl context; ``bundle``: as ``BundleRenderer``'s; ``silhouette_blend``: run the
        silhouette pass; ``background``: the clear colour (3 floats).
    Raises BadInputError when a shader of the bundle does not compile as a compute pass.
    """

    def __init__(self, ctx, moderngl, bundle, silhouette_blend: bool, background):
        self.ctx, self._mgl = ctx, moderngl
        mesh = bundle.mesh
        self._resources: list = []
        self._fbos: dict = {}
        two_layers = getattr(mesh, "core_faces", None) is not None
        self.core_faces = int(mesh.core_faces) if two_layers else 0
        try:
            self.shade = ctx.compute_shader(compute_shading_source(bundle.fragment_shader, "mesh", two_layers))
            self._resources.append(self.shade)
            self.sky = None
            if getattr(bundle, "sky_fragment_shader", None):
                self.sky = ctx.compute_shader(compute_shading_source(bundle.sky_fragment_shader, "sky"))
                self._resources.append(self.sky)
            self.blend = None
            if silhouette_blend:
                self.blend = ctx.compute_shader(compute_shading_source(SILHOUETTE_FRAGMENT_SHADER, "pass"))
                self._resources.append(self.blend)
        except (moderngl.Error, ValueError) as exc:
            self.release()
            raise BadInputError(f"the bundle's shaders do not compile as compute passes: {exc}") from None
        self.visibility = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=VISIBILITY_FRAGMENT_SHADER)
        self._resources.append(self.visibility)
        self.vao = None
        if mesh.num_faces:
            vbo = ctx.buffer(np.ascontiguousarray(mesh.vertices, np.float32).tobytes())
            ibo = ctx.buffer(np.ascontiguousarray(mesh.faces, np.int32).tobytes())
            self.vao = ctx.vertex_array(self.visibility, [(vbo, "3f", "in_position")], index_buffer=ibo,
                                        index_element_size=4)
            uvs = mesh.uvs if mesh.uvs is not None else np.zeros((mesh.num_vertices, 2), np.float32)
            vertices = np.concatenate([mesh.vertices, uvs, mesh.vertex_normals()], axis=1).astype(np.float32)
            self.vertex_ssbo = ctx.buffer(np.ascontiguousarray(vertices).tobytes())
            self._resources += [self.vao, vbo, ibo, self.vertex_ssbo]
            self.face_ssbo = ibo                 # int32 indices read as uint
        _set(self.shade, "neuras_background", (*background, 0.0))
        _set(self.shade, "neuras_write_background", 0 if self.sky is not None else 1)
        _set(self.shade, "neuras_core_faces", self.core_faces)
        for program in (self.shade, self.sky, self.blend):
            if program is not None:
                _set(program, "neuras_face", FACE_UNIT)
                _set(program, "neuras_depth", DEPTH_UNIT)
                _set(program, "neuras_out", 0)
        if self.blend is not None:
            _set(self.blend, "u_scene", SCENE_UNIT)

    def bind_texture_units(self, names_units: list[tuple[str, int]]) -> None:
        """Point the bundle's samplers (uniform name -> unit, as the renderer binds them) in both programs;
        :data:`FACE_UNIT` and :data:`SCENE_UNIT` are the passes' own."""
        for program in (self.shade, self.sky):
            if program is not None:
                for name, unit in names_units:
                    _set(program, name, unit)

    def _targets(self, width: int, height: int):
        """(visibility framebuffer, its depth and face textures, scene image, final image, final framebuffer) at
        this size."""
        key = (width, height)
        if key not in self._fbos:
            mgl = self._mgl
            face = self.ctx.texture((width, height), 1, dtype="u4")
            face.filter = (mgl.NEAREST, mgl.NEAREST)
            depth = self.ctx.depth_texture((width, height))
            depth.filter = (mgl.NEAREST, mgl.NEAREST)
            depth.compare_func = ""                          # read as values, not as a shadow comparison
            vis = self.ctx.framebuffer([face], depth)
            scene = self.ctx.texture((width, height), 4, dtype="f1")
            scene.filter = (mgl.LINEAR, mgl.LINEAR)          # the silhouette pass reads 2 x 2 block means
            scene.repeat_x = scene.repeat_y = False
            objects = [face, depth, vis, scene]
            final = scene
            if self.blend is not None:
                final = self.ctx.texture((width, height), 4, dtype="f1")
                objects.append(final)
            final_fbo = self.ctx.framebuffer([final])
            objects.append(final_fbo)
            self._fbos[key] = (vis, depth, face, scene, final, final_fbo, objects)
        return self._fbos[key][:6]

    def set_camera(self, mvp_bytes: bytes, mvp: np.ndarray, eye: np.ndarray) -> None:
        """The visibility pass's ``u_mvp`` (``projection.gl_matrix`` bytes) and the shading pass's ray uniforms
        from the (4, 4) float64 ``mvp`` and the (3,) eye, both in the bundle's frame."""
        self.visibility["u_mvp"].write(mvp_bytes)
        for name, row in (("neuras_row_x", 0), ("neuras_row_y", 1), ("neuras_row_w", 3)):
            _set(self.shade, name, tuple(float(x) for x in mvp[row, :3]))
        _set(self.shade, "neuras_eye", tuple(float(x) for x in eye))

    def draw(self, width: int, height: int, layers, cull_back_faces: bool, textures, sky_uniforms=None):
        """One frame: visibility, shading (and sky), silhouette; returns the framebuffer holding it (RGBA8,
        row 0 = bottom). ``textures``: [(unit, texture)] of the bundle; ``sky_uniforms``: callable setting the
        sky program's camera uniforms, or None to leave the sky out."""
        ctx = self.ctx
        vis, depth, face, scene, final, final_fbo = self._targets(width, height)
        vis.use()
        vis.color_mask = (False, False, False, False)     # the depth alone tells where a face is: clearing the
        vis.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)          # face ids too cost the H100 0.15 ms at 1080p
        vis.color_mask = (True, True, True, True)
        vis.use()                                         # (moderngl applies a framebuffer's masks when bound)
        if self.vao is not None:
            set_raster_state(ctx, cull_back_faces)
            draw_mesh(self.vao, self.visibility, layers)
            self.face_ssbo.bind_to_storage_buffer(0)
            self.vertex_ssbo.bind_to_storage_buffer(1)
        for unit, tex in textures:
            tex.use(location=unit)
        face.use(location=FACE_UNIT)
        depth.use(location=DEPTH_UNIT)
        scene.bind_to_image(0, read=False, write=True)
        groups = ((width + GROUP[0] - 1) // GROUP[0], (height + GROUP[1] - 1) // GROUP[1], 1)
        _set(self.shade, "neuras_size", (width, height))
        write_background = 1 if (self.sky is None or sky_uniforms is None) else 0
        _set(self.shade, "neuras_write_background", write_background)
        if self.vao is not None or write_background:     # (no faces: every pixel is background or sky)
            self.shade.run(*groups)
        if not write_background:
            sky_uniforms(self.sky)
            _set(self.sky, "neuras_size", (width, height))
            self.sky.run(*groups)
        if self.blend is not None:
            ctx.memory_barrier()
            scene.use(location=SCENE_UNIT)
            final.bind_to_image(0, read=False, write=True)
            _set(self.blend, "neuras_size", (width, height))
            self.blend.run(*groups)
        ctx.memory_barrier()
        return final_fbo

    def release(self) -> None:
        for *_, objects in self._fbos.values():
            for obj in objects:
                obj.release()
        self._fbos.clear()
        for r in reversed(self._resources):
            r.release()
        self._resources.clear()


__all__ = ["GROUP", "DEPTH_UNIT", "FACE_UNIT", "SCENE_UNIT", "compute_shading_source",
           "compute_supported", "DeferredFrame"]
