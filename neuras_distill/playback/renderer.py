"""Real-time playback of a baked bundle (this module owns ``BundleRenderer``).

The bundle's mesh is drawn with ``shaders.VERTEX_SHADER`` and the bundle's own fragment shader into an RGBA8
colour attachment (what a display shows) with a 24-bit depth buffer, depth test on, back faces culled when the
manifest says ``cull_back_faces``, cleared to ``bundle.background_color``. A two-layer mesh
(``mesh.core_faces``, manifest ``core_faces``) is drawn as ``rasterize.mesh_layers`` says: core then shell, one
draw call each with ``u_layer`` 0 / 1, so the core wins every pixel it covers (no blending: opaque rgb).
Texture binding follows docs/architecture.md ("Shader interface and texture binding"): every entry of
``bundle.textures`` (uniform name -> array) becomes a NEAREST, mipmap-free texture bound to the sampler of
that name; uint16 arrays -> R16UI..RGBA16UI (``usampler2D``), float32 arrays -> R32F..RGBA32F (``sampler2D``),
row 0 of the array = v = 0 (uploaded as is). Uniforms the compiled program optimised out are skipped.

Cameras are given in world coordinates; the renderer moves them into the bundle's frame (``bundle.origin``
subtracted in float64) before building matrices. A bundle with skyboxes is drawn in two passes: first the
mesh, then a full-screen triangle at the far plane with ``bundle.sky_fragment_shader`` and depth test "<="
without depth writes, so only pixels the mesh left empty run the skybox shader (early depth rejection); uniforms
``u_sky_origin`` = camera centre relative to the skybox centre, ``u_cam_rot``, ``u_intrinsics``,
``u_height``. ``render(..., skybox=False)`` leaves the sky pass out (the ablation
"without skyboxes": uncovered pixels get the clear colour).
"""

from __future__ import annotations

import time

import numpy as np

from ..bake.bundle import PAGED_TEXTURES, atlas_pages
from ..errors import BadInputError
from .context import get_context, moderngl_module, software_gl
from .deferred import DeferredFrame, compute_supported
from .projection import gl_matrix, mesh_bounds, near_far_for, projection_matrix, screen_box, view_matrix
from .rasterize import _check_mesh, draw_mesh, mesh_layers, mesh_vertex_array, set_raster_state
from .shaders import (
    COPY_FRAGMENT_SHADER,
    DEPTH_ONLY_FRAGMENT_SHADER,
    SILHOUETTE_FRAGMENT_SHADER,
    STRIP_VERTEX_SHADER,
    VERTEX_SHADER,
    shader_variant,
)
from .silhouette_strips import SilhouetteEdges


def _texture_layout(name: str, arr: np.ndarray) -> tuple[int, str]:
    """(components, moderngl dtype) for a bundle texture array, or BadInputError."""
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and not 1 <= arr.shape[2] <= 4):
        raise BadInputError(f"bundle texture {name!r} has shape {arr.shape}; expected (H, W) or (H, W, C), C in 1..4")
    comps = 1 if arr.ndim == 2 else int(arr.shape[2])
    if arr.dtype == np.uint16:
        return comps, "u2"
    if arr.dtype == np.float32:
        return comps, "f4"
    raise BadInputError(f"bundle texture {name!r} has dtype {arr.dtype}; expected uint16 or float32")


class BundleRenderer:
    """Draws a bundle (mesh + textures + fragment shader) for ``Cameras``.

    Args:
        bundle: object with ``mesh`` (MeshData with uvs), ``textures`` (dict uniform name -> np array),
            ``fragment_shader`` (GLSL source, ``#version 400 core`` from bake/glsl.py; see shaders.py for its
            interface), ``background_color`` (3 floats).
        ctx: moderngl context (default :func:`context.get_context`).
        silhouette_blend: run the soft-silhouette pass (``silhouette.py``) after the scene; default: the
            bundle manifest's ``silhouette_blend`` (bundles from before it have none and play without).
        silhouette_tiles: run that pass on the screen tiles along the silhouette edges, found on the host each
            frame (``silhouette_strips.py``), instead of over the mesh's screen box; default: on software GL only.
            A rasterizing GPU shades the box in microseconds, while finding the tiles costs the host a
            millisecond or more per frame (the H100 drew the demo's 1080p frame in 0.73 ms of GPU time and
            3.27 ms of wall time). Both give the same picture.
        depth_prepass: draw the mesh's depth alone first, then shade with depth test "<=" and no depth writes,
            so each pixel runs the neural shader once instead of once per fragment that passes the test in draw
            order; default: for two-layer meshes on a rasterizing GPU. Measured on an H200 at 1920 x 1080 (GPU
            time per frame, GL timer queries): the from-ngp ball's two layers 1.225 -> 1.065 ms, but the
            one-layer demo 1.005 -> 1.074 and street 2.893 -> 3.078 ms; on llvmpipe it costs 15-20% everywhere.
            Forward shading only (the deferred path shades each pixel once by construction).
        shading: "forward" (the mesh's fragments run the bundle's shader) or "deferred" (a visibility buffer,
            then the shaders as compute passes: ``deferred.py``); default: deferred on a rasterizing GPU whose
            GL compiles compute shaders, forward on software GL (there about 3x faster: demo 1080p 34 against
            105 ms on llvmpipe). Measured on an
            H100 at 1920 x 1080: see ``deferred.py``. Both give the same picture up to the barycentrics'
            rounding.

    Call :meth:`release` (or use as a context manager) to free the GL objects early.
    """

    def __init__(self, bundle, ctx=None, silhouette_blend: bool | None = None, silhouette_tiles: bool | None = None,
                 depth_prepass: bool | None = None, shading: str | None = None):
        moderngl = moderngl_module()
        self._mgl = moderngl
        self.ctx = ctx if ctx is not None else get_context()
        self.bundle = bundle
        mesh = bundle.mesh
        _check_mesh(mesh)
        self.background = tuple(float(c) for c in np.asarray(bundle.background_color, np.float64).reshape(3))
        self._bounds = mesh_bounds(mesh.vertices)
        self._fbo_cache: dict = {}
        self._resources: list = []
        manifest = getattr(bundle, "manifest", None) or {}
        self.silhouette_blend = bool(manifest.get("silhouette_blend", False) if silhouette_blend is None
                                     else silhouette_blend)
        self._textures: list = []
        self._layers = mesh_layers(mesh)
        # one program per mesh layer (a two-layer bundle's shader holds a variant per layer, glsl.shader_variant)
        self.programs: dict = {}
        try:
            for layer in sorted({max(0, int(layer)) for layer, _, _ in self._layers} or {0}):
                self.programs[layer] = self.ctx.program(
                    vertex_shader=VERTEX_SHADER, fragment_shader=shader_variant(bundle.fragment_shader, layer))
        except moderngl.Error as exc:
            raise BadInputError(f"the bundle's fragment shader does not compile or link: {exc}") from None
        self.program = self.programs[min(self.programs)]
        self._resources += list(self.programs.values())
        self.origin = np.asarray(getattr(bundle, "origin", np.zeros(3)), np.float64).reshape(3)
        self.sky_program = self.sky_vao = None
        self.sky_center = None
        if getattr(bundle, "sky_fragment_shader", None):
            from ..bake.glsl_sky import SKY_VERTEX_SHADER

            try:
                self.sky_program = self.ctx.program(vertex_shader=SKY_VERTEX_SHADER,
                                                     fragment_shader=bundle.sky_fragment_shader)
            except moderngl.Error as exc:
                raise BadInputError(f"the bundle's skybox shader does not compile or link: {exc}") from None
            self.sky_vao = self.ctx.vertex_array(self.sky_program, [])
            self._resources += [self.sky_program, self.sky_vao]
            self.sky_center = np.asarray(bundle.manifest["skybox"]["center"], np.float64).reshape(3)
        self.blend_program = self.copy_program = self.strip_vbo = None
        software = software_gl(str(self.ctx.info.get("GL_RENDERER", "")))
        self.silhouette_tiles = software if silhouette_tiles is None else bool(silhouette_tiles)
        two_layers = getattr(mesh, "core_faces", None) is not None
        self.depth_prepass = (two_layers and not software) if depth_prepass is None else bool(depth_prepass)
        self.edges = None
        if self.silhouette_blend:          # the pass on strips along the silhouette (silhouette_strips.py)
            if self.silhouette_tiles:
                self.edges = SilhouetteEdges(mesh.vertices, mesh.faces)
            self.blend_program = self.ctx.program(vertex_shader=STRIP_VERTEX_SHADER,
                                                  fragment_shader=SILHOUETTE_FRAGMENT_SHADER)
            self.copy_program = self.ctx.program(vertex_shader=STRIP_VERTEX_SHADER,
                                                 fragment_shader=COPY_FRAGMENT_SHADER)
            self.strip_vbo = self.ctx.buffer(reserve=4096, dynamic=True)
            self.blend_vao = self.ctx.vertex_array(self.blend_program, [(self.strip_vbo, "2f", "in_ndc")])
            self.copy_vao = self.ctx.vertex_array(self.copy_program, [(self.strip_vbo, "2f", "in_ndc")])
            self._resources += [self.blend_vao, self.copy_vao, self.strip_vbo, self.blend_program,
                                self.copy_program]
        self.vaos: dict = {}
        for layer, program in self.programs.items():
            if mesh.num_faces:
                self.vaos[layer], bufs = mesh_vertex_array(self.ctx, program, mesh)
                self._resources += [self.vaos[layer], *bufs]
        self.vao = self.vaos.get(min(self.programs))
        self.depth_program = self.depth_vao = None
        if self.depth_prepass and mesh.num_faces:
            self.depth_program = self.ctx.program(vertex_shader=VERTEX_SHADER,
                                                  fragment_shader=DEPTH_ONLY_FRAGMENT_SHADER)
            self.depth_vao, bufs = mesh_vertex_array(self.ctx, self.depth_program, mesh)
            self._resources += [self.depth_vao, *bufs, self.depth_program]
        max_size = int(self.ctx.info.get("GL_MAX_TEXTURE_SIZE", 0) or 0)
        max_layers = int(self.ctx.info.get("GL_MAX_ARRAY_TEXTURE_LAYERS", 0) or 0)
        pages = atlas_pages(manifest)
        for unit, (name, arr) in enumerate(sorted(bundle.textures.items())):
            arr = np.ascontiguousarray(arr)
            comps, dtype = _texture_layout(name, arr)
            h, w = arr.shape[:2]
            if pages > 1 and name in PAGED_TEXTURES:        # the atlas's pages as the layers of a texture array
                if (max_size and w > max_size) or (max_layers and pages > max_layers):
                    raise BadInputError(f"the bundle's atlas has {pages} pages of {w}x{w} texels; this GL holds "
                                        f"at most {max_size}x{max_size} per page and {max_layers} pages: bake it "
                                        f"again with texture.page_size {min(w, max_size)} or less")
                tex = self.ctx.texture_array((w, h // pages, pages), comps, arr.tobytes(), dtype=dtype, alignment=1)
            else:
                if max_size and max(h, w) > max_size:
                    raise BadInputError(f"bundle texture {name!r} is {w}x{h}; this GL allows at most {max_size} "
                                        "per side")
                tex = self.ctx.texture((w, h), comps, arr.tobytes(), dtype=dtype, alignment=1)
            tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
            tex.repeat_x = tex.repeat_y = False
            self._resources.append(tex)
            self._textures.append((unit, tex))
            for program in (*self.programs.values(), self.sky_program):
                if program is not None and name in program:
                    program[name].value = unit
        if shading not in (None, "forward", "deferred"):
            raise ValueError(f"shading must be 'forward' or 'deferred', got {shading!r}")
        automatic = shading is None
        if automatic:
            shading = "deferred" if (not software and compute_supported(self.ctx)) else "forward"
        self.deferred = None
        if shading == "deferred":
            try:
                self.deferred = DeferredFrame(self.ctx, moderngl, bundle, self.silhouette_blend, self.background)
            except BadInputError:
                if not automatic:                # asked for by name: say why it cannot be
                    raise
                shading = "forward"              # a shader outside the compute interface still plays forward
        self.shading = shading
        if self.deferred is not None:
            self._resources.append(self.deferred)
            self.deferred.bind_texture_units([(name, unit) for unit, (name, _) in
                                              enumerate(sorted(bundle.textures.items()))])

    # ------------------------------------------------------------------ internals
    def _fbo(self, width: int, height: int):
        """(scene framebuffer, colour attachment, (blend framebuffer, its texture) or None, objects) at this size.
        Without the silhouette pass the colour is a renderbuffer; with it, the scene renders into an RGBA8
        texture and the pass blends tiles of it into a second one, then copies them back (silhouette_strips.py)."""
        key = (width, height)
        if key not in self._fbo_cache:
            objects = []
            blended = None
            if self.silhouette_blend:
                color = self._linear_texture(width, height)
                blended_color = self._linear_texture(width, height)
                blended = (self.ctx.framebuffer([blended_color]), blended_color)
                objects += list(blended)
            else:
                color = self.ctx.renderbuffer((width, height), 4, dtype="f1")
            depth = self.ctx.depth_renderbuffer((width, height))
            scene = self.ctx.framebuffer([color], depth)
            objects += [scene, color, depth]
            self._fbo_cache[key] = (scene, color, blended, objects)
        return self._fbo_cache[key]

    def _linear_texture(self, width: int, height: int):
        """An RGBA8 texture read with LINEAR filtering (2 x 2 block means, silhouette.py), clamped at the edges."""
        tex = self.ctx.texture((width, height), 4, dtype="f1")
        tex.filter = (self._mgl.LINEAR, self._mgl.LINEAR)
        tex.repeat_x = tex.repeat_y = False
        return tex

    def _local_view(self, cameras, i: int, near_far: tuple[float, float] | None = None
                    ) -> tuple[np.ndarray, np.ndarray]:
        """(c2w, mvp): world camera ``i``'s (4, 4) float64 pose in the bundle's frame (``origin`` subtracted in
        float64, then rounded to float32 like every camera) and its model-view-projection with the tight
        near / far of the mesh's box (``projection.near_far_for``), or the given ``near_far`` (view-axis
        distances)."""
        c2w = cameras.c2w[i].double().numpy().copy()
        c2w[:3, 3] -= self.origin
        c2w = c2w.astype(np.float32).astype(np.float64)
        near, far = near_far if near_far is not None else near_far_for(self._bounds, c2w[:3, 3], c2w)
        proj = projection_matrix(float(cameras.fx[i]), float(cameras.fy[i]), float(cameras.cx[i]),
                                 float(cameras.cy[i]), cameras.width, cameras.height, near, far)
        return c2w, proj @ view_matrix(c2w)

    def _set_camera(self, c2w: np.ndarray, mvp: np.ndarray) -> None:
        """Uniforms of the mesh programs for a camera in the bundle's frame (:meth:`_local_view`)."""
        mvp = gl_matrix(mvp)
        for program in self.programs.values():
            if "u_mvp" in program:
                program["u_mvp"].write(mvp)
            if "u_cam_pos" in program:
                program["u_cam_pos"].value = tuple(float(x) for x in c2w[:3, 3])

    @property
    def cull_back_faces(self) -> bool:
        """Whether the bundle was trained (and so plays) with back faces culled (manifest ``cull_back_faces``)."""
        return bool((getattr(self.bundle, "manifest", None) or {}).get("cull_back_faces", False))

    def _draw_sky(self, world_cameras, i: int) -> None:
        self._sky_uniforms(self.sky_program, world_cameras, i)
        ctx = self.ctx
        ctx.disable(self._mgl.CULL_FACE)
        ctx.enable(self._mgl.DEPTH_TEST)
        ctx.depth_func = "<="
        fbo = ctx.fbo
        fbo.depth_mask = False
        try:
            self.sky_vao.render(self._mgl.TRIANGLES, vertices=3)
        finally:
            fbo.depth_mask = True

    def _sky_uniforms(self, p, world_cameras, i: int) -> None:
        """The skybox shader's camera uniforms (in program ``p``: the sky pass's, or the deferred sky's)."""
        c2w = world_cameras.c2w[i].double().numpy()
        if "u_sky_origin" in p:
            p["u_sky_origin"].value = tuple(float(x) for x in c2w[:3, 3] - self.sky_center)
        if "u_cam_rot" in p:
            p["u_cam_rot"].value = tuple(float(x) for x in c2w[:3, :3].T.reshape(-1))  # column-major
        if "u_intrinsics" in p:
            p["u_intrinsics"].value = (float(world_cameras.fx[i]), float(world_cameras.fy[i]),
                                       float(world_cameras.cx[i]), float(world_cameras.cy[i]))
        if "u_height" in p:
            p["u_height"].value = float(world_cameras.height)

    def draw(self, cameras, i: int, skybox: bool = True):
        """Draw world camera ``i`` at the cameras' size and return the moderngl framebuffer that holds the
        frame (RGBA8, row 0 = bottom, valid until the next draw): :meth:`render` reads it back, the window
        player (``window.py``) blits it to the screen."""
        if self.deferred is not None:
            return self._draw_deferred(cameras, i, skybox)
        fbo, scene_color, blended, _ = self._fbo(int(cameras.width), int(cameras.height))
        fbo.use()
        fbo.clear(*self.background, 0.0, depth=1.0)     # alpha 0: no mesh (the mesh shaders write 1)
        for unit, tex in self._textures:
            tex.use(location=unit)
        set_raster_state(self.ctx, self.cull_back_faces)
        c2w, mvp = self._local_view(cameras, i)
        if self.vao is not None:
            self._set_camera(c2w, mvp)
            if self.depth_vao is not None:
                self._depth_prepass(fbo, mvp)
            for call in self._layers:               # core first: its pixels then fail the shell's depth test
                layer = max(0, int(call[0]))
                draw_mesh(self.vaos[layer], self.programs[layer], [call])
            if self.depth_vao is not None:
                fbo.depth_mask = True
                self.ctx.depth_func = "<"
        if skybox and self.sky_program is not None:
            self._draw_sky(cameras, i)         # after the mesh: only the pixels it left empty are shaded
        if blended is not None:                 # the soft-silhouette pass (silhouette.py)
            self._blend_silhouettes(c2w, mvp, (int(cameras.width), int(cameras.height)), fbo, scene_color, *blended)
        return fbo

    def draw_mesh_into(self, cameras, i: int, near_far: tuple[float, float]) -> None:
        """Draw the mesh alone (no clear, no skyboxes, no silhouette pass) of world camera ``i`` into the bound
        framebuffer, depth-tested against what is there, with the projection's planes at ``near_far`` (view-axis
        distances, the same for every bundle drawn into that framebuffer): several bundles (the tiles of a
        tileset, ``playback/tiles.py``) then meet in one depth buffer."""
        for unit, tex in self._textures:
            tex.use(location=unit)
        set_raster_state(self.ctx, self.cull_back_faces)
        c2w, mvp = self._local_view(cameras, i, near_far)
        if self.vao is None:
            return
        self._set_camera(c2w, mvp)
        for call in self._layers:
            draw_mesh(self.vaos[max(0, int(call[0]))], self.programs[max(0, int(call[0]))], [call])

    def _draw_deferred(self, cameras, i: int, skybox: bool):
        """:meth:`draw` by the deferred path (``deferred.py``)."""
        c2w, mvp = self._local_view(cameras, i)
        d = self.deferred
        d.set_camera(gl_matrix(mvp), mvp, c2w[:3, 3])
        if "u_cam_pos" in d.shade:
            d.shade["u_cam_pos"].value = tuple(float(x) for x in c2w[:3, 3])
        sky = None
        if skybox and d.sky is not None:
            def sky(program):
                self._sky_uniforms(program, cameras, i)
        return d.draw(int(cameras.width), int(cameras.height), self._layers, self.cull_back_faces, self._textures,
                      sky)

    def _depth_prepass(self, fbo, mvp: np.ndarray) -> None:
        """Every layer's depth without colour (the same vertex stage, ``invariant gl_Position``), then the state
        the shading pass runs in: depth test "<=" (only the fragment that won the prepass), no depth writes.
        The caller restores the depth mask and "<" after the shading pass."""
        program = self.depth_program
        if "u_mvp" in program:
            program["u_mvp"].write(gl_matrix(mvp))
        fbo.color_mask = (False, False, False, False)
        draw_mesh(self.depth_vao, program, self._layers)
        fbo.color_mask = (True, True, True, True)
        fbo.depth_mask = False
        self.ctx.depth_func = "<="

    def _blend_silhouettes(self, c2w, mvp, size, scene, scene_color, blended, blended_color) -> None:
        """The silhouette pass on the screen tiles along the mesh's silhouette and boundary edges
        (silhouette_strips.py): blend those tiles of the scene into ``blended``, then copy them back. Over the
        mesh's whole screen box (and a full-frame copy) it cost the demo 30 of its 75 ms at 1080p on llvmpipe;
        every pixel it changes lies in the tiles, so the picture is the same. Without ``silhouette_tiles`` (a
        rasterizing GPU) it runs over the box."""
        ctx = self.ctx
        w, h = size
        box = screen_box(self._bounds, mvp, w, h)
        quads = (self.edges.pass_quads(c2w[:3, 3], mvp, w, h, box) if self.edges is not None
                 else SilhouetteEdges.rect_quads(*box, w, h))
        if len(quads) == 0:
            return
        data = quads.tobytes()
        if self.strip_vbo.size < len(data):
            self.strip_vbo.orphan(2 * len(data))
        self.strip_vbo.write(data)
        ctx.disable(self._mgl.DEPTH_TEST | self._mgl.CULL_FACE)
        blended.use()
        scene_color.use(location=0)
        self.blend_program["u_scene"].value = 0
        self.blend_vao.render(self._mgl.TRIANGLES, vertices=len(quads))
        scene.use()
        blended_color.use(location=0)
        self.copy_program["u_blended"].value = 0
        self.copy_vao.render(self._mgl.TRIANGLES, vertices=len(quads))

    # ------------------------------------------------------------------ public
    def render(self, cameras, i: int, skybox: bool = True) -> np.ndarray:
        """(H, W, 3) float32 image in [0, 1] of world camera ``i`` (row 0 = top), quantised to 8 bits like a
        display. ``skybox=False`` leaves the skybox pass out (uncovered pixels get the clear colour)."""
        h, w = int(cameras.height), int(cameras.width)
        fbo = self.draw(cameras, i, skybox)
        data = np.frombuffer(fbo.read(components=3, alignment=1, dtype="f1"), np.uint8).reshape(h, w, 3)[::-1]
        return data.astype(np.float32) / 255.0

    def time_frames(self, cameras, indices=None, warmup: int = 5, frames: int = 30) -> dict:
        """Frame times of full draws at the cameras' resolution, three ways.

        * ``median_ms`` (the speedup's figure): wall time of one draw with ``ctx.finish()`` before the clock
          stops: the latency of a frame, host work (Python, uniforms, the silhouette strips) and GPU work in
          series;
        * ``gpu_median_ms``: the GPU's own time for the same draws, from GL timer queries (``GL_TIME_ELAPSED``;
          None where the driver has no timer queries);
        * ``pipelined_ms``: ``frames`` draws issued back to back with one ``finish`` at the end, divided by the
          count: what a player loop without vsync sustains, with the host preparing frame k+1 while the GPU
          draws frame k.

        Cycles through ``indices`` (default all cameras); ``warmup`` frames are drawn first and not counted.
        Returns ``{"median_ms", "p10_ms", "p90_ms", "fps" (1000 / median_ms), "frames", "resolution" [W, H],
        "times_ms" (every timed frame, in order), "gpu_median_ms", "pipelined_ms", "pipelined_fps", "shading"}``
        (``shading``: "forward" or "deferred", the path that drew them).
        """
        idx = list(range(len(cameras))) if indices is None else [int(k) for k in indices]
        if not idx:
            raise ValueError("time_frames needs at least one camera index")
        frames = max(1, int(frames))
        for k in range(max(0, int(warmup))):
            self.draw(cameras, idx[k % len(idx)])
        self.ctx.finish()
        times = np.empty(frames, np.float64)
        for k in range(frames):
            t0 = time.perf_counter()
            self.draw(cameras, idx[k % len(idx)])
            self.ctx.finish()
            times[k] = (time.perf_counter() - t0) * 1000.0
        gpu = self._gpu_times(cameras, idx, frames)
        t0 = time.perf_counter()
        for k in range(frames):
            self.draw(cameras, idx[k % len(idx)])
        self.ctx.finish()
        pipelined = (time.perf_counter() - t0) * 1000.0 / frames
        median = float(np.median(times))
        return {"median_ms": median, "p10_ms": float(np.percentile(times, 10)),
                "p90_ms": float(np.percentile(times, 90)),
                "fps": 1000.0 / median if median > 0 else float("inf"), "frames": frames,
                "resolution": [int(cameras.width), int(cameras.height)], "times_ms": times.tolist(),
                "gpu_median_ms": gpu, "pipelined_ms": pipelined,
                "pipelined_fps": 1000.0 / pipelined if pipelined > 0 else float("inf"), "shading": self.shading}

    def _gpu_times(self, cameras, idx: list[int], frames: int) -> float | None:
        """Median GPU time in ms of ``frames`` draws (GL timer queries), None when the driver has none or
        rasterizes in software (llvmpipe's queries time the command submission, not its threads' rasterizing:
        7.9 ms of a 59 ms demo frame at 1080p here)."""
        if software_gl(str(self.ctx.info.get("GL_RENDERER", ""))):
            return None
        try:
            query = self.ctx.query(time=True)
        except Exception:                       # noqa: BLE001 - moderngl raises its own Error without the extension
            return None
        elapsed = []
        for k in range(frames):
            with query:
                self.draw(cameras, idx[k % len(idx)])
            self.ctx.finish()
            elapsed.append(query.elapsed / 1e6)  # nanoseconds
        if hasattr(query, "release"):
            query.release()
        return float(np.median(elapsed)) if elapsed and max(elapsed) > 0 else None

    def release(self) -> None:
        """Free the GL objects (program, buffers, textures, framebuffers)."""
        for *_, objects in self._fbo_cache.values():
            for obj in objects:
                obj.release()
        self._fbo_cache.clear()
        for r in reversed(self._resources):
            r.release()
        self._resources.clear()
        self._textures.clear()
        self.vao = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
