"""G-buffer rasterization of a mesh for a set of cameras (this module owns ``rasterize_gbuffer``).

One framebuffer with three colour attachments -- RG32F uv, R32I face id, R32F view depth -- and a 24-bit depth
buffer; depth test on (GL_LESS, first drawn wins ties), back faces culled unless ``cull_back_faces=False``
(on by default, as ``geometry.cull_back_faces``; see :func:`set_raster_state`), one sample at each pixel
centre (no MSAA). The vertex stage is ``shaders.VERTEX_SHADER``, the same one playback uses, and
the projection is ``projection.mvp_for`` (the pixel-centre convention of ``Cameras.rays``). Read-back flips the
rows so row 0 is the top of the image.

Two-layer meshes (``MeshData.core_faces``) are drawn by :func:`draw_mesh` in two draw calls, core then shell,
with the vertex uniform ``u_layer`` giving each layer its half of the depth range (``shaders.py``): per pixel the
nearest core fragment, else the nearest shell fragment. Face ids stay global (``u_face_offset``) and the depth
attachment holds the true view-space depth. :func:`mesh_layers` is the one place that turns a mesh into draw
calls; playback (``renderer.py``) uses it too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry.mesh import MeshData
from .context import get_context, moderngl_module
from .gbuffer import GBuffer
from .projection import camera_near_far, gl_matrix, mesh_bounds, mvp_for, view_matrix
from .shaders import GBUFFER_FRAGMENT_SHADER, VERTEX_SHADER

#: ``u_layer`` values (shaders.VERTEX_SHADER): one layer (depth as projected), the core, the shell.
SINGLE_LAYER, CORE_LAYER, SHELL_LAYER = -1.0, 0.0, 1.0


def _empty_gbuffer(n: int, h: int, w: int) -> GBuffer:
    return GBuffer(uv=np.zeros((n, h, w, 2), np.float32), face_id=np.full((n, h, w), -1, np.int32),
                   coverage=np.zeros((n, h, w), bool), depth=np.full((n, h, w), np.inf, np.float32),
                   normal=np.zeros((n, h, w, 3), np.float32))


def set_raster_state(ctx, cull_back_faces: bool) -> None:
    """The one raster state shared by G-buffers and playback: depth test "<", no blending, and back faces
    (clockwise in the window: faces seen from inside a closed mesh) culled when ``cull_back_faces``. Culling
    changes nothing visible on a closed mesh and skips shading the hidden half of it."""
    moderngl = moderngl_module()
    ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.depth_func = "<"
    if cull_back_faces:
        ctx.front_face = "ccw"
        ctx.cull_face = "back"
        ctx.enable(moderngl.CULL_FACE)


def mesh_vertex_array(ctx, program, mesh: MeshData):
    """(vao, [buffers]) drawing ``mesh`` as indexed triangles with attributes in_position / in_uv / in_normal
    (``MeshData.vertex_normals``).

    ``mesh.uvs`` None is drawn with uv = 0. Attributes the program does not use are skipped (and normals are
    then not computed). The caller releases the vao and the buffers.
    """
    uvs = mesh.uvs if mesh.uvs is not None else np.zeros((mesh.num_vertices, 2), np.float32)
    use_normals = "in_normal" in program
    columns = [mesh.vertices, uvs] + ([mesh.vertex_normals()] if use_normals else [])
    interleaved = np.ascontiguousarray(np.concatenate(columns, axis=1), dtype=np.float32)
    vbo = ctx.buffer(interleaved.tobytes())
    ibo = ctx.buffer(np.ascontiguousarray(mesh.faces, dtype=np.int32).tobytes())
    fmt, names = ["3f"], ["in_position"]
    if "in_uv" in program:
        fmt.append("2f")
        names.append("in_uv")
    else:
        fmt.append("8x")
    if use_normals:
        fmt.append("3f")
        names.append("in_normal")
    vao = ctx.vertex_array(program, [(vbo, " ".join(fmt), *names)], index_buffer=ibo, index_element_size=4)
    return vao, [vbo, ibo]


def mesh_layers(mesh: MeshData) -> list[tuple[float, int, int]]:
    """The draw calls of ``mesh``: [(u_layer, first face, face count)], empty ranges left out.

    A single-layer mesh (``core_faces`` None) is one call with :data:`SINGLE_LAYER`; a two-layer mesh is the
    core (faces[:core_faces], :data:`CORE_LAYER`) then the shell (:data:`SHELL_LAYER`). Core first: the shell's
    fragments behind the core then fail the depth test before they are shaded.
    """
    f = mesh.num_faces
    core = getattr(mesh, "core_faces", None)
    if core is None:
        return [(SINGLE_LAYER, 0, f)] if f else []
    core = int(core)
    return [(layer, first, count) for layer, first, count in ((CORE_LAYER, 0, core), (SHELL_LAYER, core, f - core))
            if count > 0]


def draw_mesh(vao, program, layers: list[tuple[float, int, int]]) -> None:
    """Draw ``mesh_layers(mesh)`` with ``vao`` (from :func:`mesh_vertex_array`): per layer set ``u_layer`` and,
    where the program has it, ``u_face_offset`` (the first face, so gl_PrimitiveID + offset is the global face
    index), then draw that range of the index buffer."""
    moderngl = moderngl_module()
    for layer, first, count in layers:
        if "u_layer" in program:
            program["u_layer"].value = layer
        if "u_face_offset" in program:
            program["u_face_offset"].value = first
        vao.render(moderngl.TRIANGLES, vertices=3 * count, first=3 * first)


def _check_mesh(mesh: MeshData) -> None:
    if mesh.num_faces and (int(mesh.faces.min()) < 0 or int(mesh.faces.max()) >= mesh.num_vertices):
        raise ValueError(f"mesh faces index vertices outside [0, {mesh.num_vertices})")
    if mesh.uvs is not None and mesh.uvs.shape[0] != mesh.num_vertices:
        raise ValueError(f"mesh has {mesh.uvs.shape[0]} uvs for {mesh.num_vertices} vertices")
    core = getattr(mesh, "core_faces", None)
    if core is not None and (isinstance(core, bool) or not isinstance(core, (int, np.integer))
                             or not 0 <= int(core) <= mesh.num_faces):
        raise ValueError(f"mesh core_faces must be None or an integer in [0, {mesh.num_faces}], got {core!r}")


def rasterize_gbuffer(mesh: MeshData, cameras, *, ctx=None, cull_back_faces: bool = True,
                      out: Path | None = None) -> GBuffer:
    """Rasterize ``mesh`` for every camera of ``cameras``.

    Args:
        mesh: world-space MeshData; ``uvs`` may be None (then ``uv`` is all zeros). With ``core_faces`` set, the
            nearest core face wins at every pixel a core face covers, the nearest shell face elsewhere.
        cameras: ``Cameras`` (N cameras, W x H).
        ctx: moderngl context (default :func:`context.get_context`).
        cull_back_faces: cull faces seen from behind (both layers alike).
        out: a folder to write the arrays into as they are read back, one ``<attribute>.npy`` each (the names
            of :class:`GBuffer`'s fields); the result then holds them memory-mapped, never all in memory.
    Returns:
        GBuffer with uv (N, H, W, 2) f32 (0 where empty), face_id (N, H, W) i32 (index into ``mesh.faces``,
        -1 where empty), coverage (N, H, W) bool, depth (N, H, W) f32 view-space depth along -z of the visible
        face (inf where empty), normal (N, H, W, 3) f32 unit interpolated vertex normal (0 where empty).
    """
    n, w, h = len(cameras), int(cameras.width), int(cameras.height)
    _check_mesh(mesh)
    if mesh.num_faces == 0:
        empty = _empty_gbuffer(n, h, w)
        if out is not None:
            for name in ("uv", "face_id", "coverage", "depth", "normal"):
                np.save(Path(out) / f"{name}.npy", getattr(empty, name), allow_pickle=False)
        return empty
    ctx = ctx if ctx is not None else get_context()
    moderngl = moderngl_module()

    bounds = mesh_bounds(mesh.vertices)
    uv, face, coverage, depth, normal = (_output_array(out, name, shape, dtype) for name, shape, dtype in (
        ("uv", (n, h, w, 2), np.float32), ("face_id", (n, h, w), np.int32), ("coverage", (n, h, w), bool),
        ("depth", (n, h, w), np.float32), ("normal", (n, h, w, 3), np.float32)))

    resources = []
    try:
        prog = ctx.program(vertex_shader=VERTEX_SHADER, fragment_shader=GBUFFER_FRAGMENT_SHADER)
        resources.append(prog)
        vao, bufs = mesh_vertex_array(ctx, prog, mesh)
        resources += [vao, *bufs]
        layers = mesh_layers(mesh)
        tex_uv = ctx.texture((w, h), 2, dtype="f4")
        tex_face = ctx.texture((w, h), 1, dtype="i4")
        tex_depth = ctx.texture((w, h), 1, dtype="f4")
        tex_normal = ctx.texture((w, h), 4, dtype="f4")
        for t in (tex_uv, tex_face, tex_depth, tex_normal):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        depth_rb = ctx.depth_renderbuffer((w, h))
        fbo = ctx.framebuffer([tex_uv, tex_face, tex_depth, tex_normal], depth_rb)
        resources += [tex_uv, tex_face, tex_depth, tex_normal, depth_rb, fbo]

        fbo.use()
        set_raster_state(ctx, cull_back_faces)
        for i in range(n):
            near, far = camera_near_far(bounds, cameras, i)
            prog["u_mvp"].write(gl_matrix(mvp_for(cameras, i, near, far)))
            view = view_matrix(cameras.c2w[i].double().numpy())
            prog["u_view_z"].value = tuple(float(x) for x in view[2])
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            draw_mesh(vao, prog, layers)
            # the shader writes face id + 1 so that the cleared value 0 means "empty"
            face[i] = np.frombuffer(fbo.read(components=1, attachment=1, dtype="i4"), np.int32).reshape(h, w)[::-1] - 1
            covered = face[i] >= 0
            coverage[i] = covered
            empty = ~covered
            uv[i] = np.frombuffer(fbo.read(components=2, attachment=0, dtype="f4"), np.float32).reshape(h, w, 2)[::-1]
            depth[i] = np.frombuffer(fbo.read(components=1, attachment=2, dtype="f4"), np.float32).reshape(h, w)[::-1]
            normal[i] = np.frombuffer(fbo.read(components=3, attachment=3, dtype="f4"),
                                      np.float32).reshape(h, w, 3)[::-1]
            depth[i][empty] = np.inf
            uv[i][empty] = 0.0
            normal[i][empty] = 0.0
    finally:
        for r in reversed(resources):
            r.release()
    for array in (uv, face, coverage, depth, normal):
        if isinstance(array, np.memmap):
            array.flush()
    return GBuffer(uv=uv, face_id=face, coverage=coverage, depth=depth, normal=normal)


def _output_array(out: Path | None, name: str, shape: tuple, dtype) -> np.ndarray:
    """An array to fill view by view: in memory, or ``out / <name>.npy`` memory-mapped."""
    if out is None:
        return np.empty(shape, dtype)
    return np.lib.format.open_memmap(Path(out) / f"{name}.npy", mode="w+", dtype=dtype, shape=shape)
