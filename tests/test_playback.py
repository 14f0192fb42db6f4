"""Playback stage: projection convention, G-buffer rasterization, bundle playback (headless EGL)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from neuras_distill.geometry.mesh import MeshData
from neuras_distill.playback.projection import mvp_for, near_far_for, projection_matrix, view_matrix
from neuras_distill.render.cameras import Cameras, look_at


def _odd_cameras() -> Cameras:
    """Two cameras, non-square 96x64 image, fx != fy, off-centre principal point."""
    poses = torch.stack([look_at(torch.tensor([0.7, -0.4, 3.0]), torch.tensor([0.1, 0.2, 0.0]),
                                 torch.tensor([0.0, 1.0, 0.0])),
                         look_at(torch.tensor([-1.5, 0.8, 2.2]), torch.tensor([0.0, -0.1, 0.1]),
                                 torch.tensor([0.0, 0.0, 1.0]))]).float()
    return Cameras(poses, [70.0, 83.0], [55.0, 61.0], [40.3, 51.9], [36.7, 27.2], 96, 64)


def _ray(cameras: Cameras, i: int, u: int, v: int) -> tuple[np.ndarray, np.ndarray]:
    o, d = cameras.rays(i)
    return o[v, u].double().numpy(), d[v, u].double().numpy()


# ---------------------------------------------------------------------------------------------- no GL needed
def test_projection_maps_rays_to_gl_pixel_centres():
    cams = _odd_cameras()
    w, h = cams.width, cams.height
    for i in range(len(cams)):
        near, far = 0.5, 20.0
        mvp = mvp_for(cams, i, near, far)
        o, d = cams.rays(i)
        for (u, v) in [(0, 0), (95, 63), (17, 40), (60, 5)]:
            p = o[v, u].double().numpy() + 3.0 * d[v, u].double().numpy()
            clip = mvp @ np.append(p, 1.0)
            ndc = clip[:3] / clip[3]
            x_win, y_win = (ndc[0] + 1) * w / 2, (ndc[1] + 1) * h / 2
            # (float32 rays: 1e-4 px; a convention error would be >= 0.5 px)
            assert x_win == pytest.approx(u + 0.5, abs=1e-4)
            assert y_win == pytest.approx((h - 1 - v) + 0.5, abs=1e-4)  # GL row y_gl = H-1-v, centre +0.5
            depth = -(view_matrix(cams.c2w[i].double().numpy()) @ np.append(p, 1.0))[2]
            assert -1 < ndc[2] < 1 and near < depth < far
    p = projection_matrix(100, 100, 50, 50, 100, 100, 1.0, 10.0)
    assert p @ np.array([0, 0, -1.0, 1]) == pytest.approx([0, 0, -1.0, 1.0])  # near plane -> ndc z = -1


def test_near_far_is_tight_and_contains_the_box():
    bounds = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    c2w = look_at(torch.tensor([0.0, 0.0, 4.0]), torch.zeros(3), torch.tensor([0.0, 1.0, 0.0])).numpy()
    near, far = near_far_for(bounds, c2w[:3, 3], c2w)
    assert 2.9 < near < 3.0 and 5.0 < far < 5.1
    n2, f2 = near_far_for(bounds, c2w[:3, 3])  # centre only: looser but still valid
    assert 0 < n2 <= near and f2 >= math.sqrt(4 ** 2 + 2) and n2 < f2
    n3, f3 = near_far_for(bounds, [0.0, 0.0, 0.0], np.eye(4))  # camera inside the box
    assert 0 < n3 < 1e-3 * f3 * 10 and f3 > 1.0


# ---------------------------------------------------------------------------------------------- G-buffer
@pytest.mark.parametrize("i", [0, 1])
@pytest.mark.gl
def test_tiny_triangle_covers_exactly_its_pixel(i):
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    cams = _odd_cameras()
    u, v, z = 23, 41, 2.5
    fx, fy, cx, cy = (float(t[i]) for t in (cams.fx, cams.fy, cams.cx, cams.cy))
    xc, yc = (u + 0.5 - cx) / fx * z, -(v + 0.5 - cy) / fy * z  # camera-space point of that pixel centre
    offs = [(-0.4, -0.4), (0.4, -0.4), (0.0, 0.45)]  # in pixels: contains the centre, no neighbour centre
    tri_cam = np.array([[xc + a * z / fx, yc + b * z / fy, -z, 1.0] for a, b in offs])
    tri = (cams.c2w[i].double().numpy() @ tri_cam.T).T[:, :3]
    gb = rasterize_gbuffer(MeshData(tri, [[0, 1, 2]], np.zeros((3, 2))), cams[i])
    covered = np.argwhere(gb.coverage[0])
    assert covered.tolist() == [[v, u]]
    assert gb.face_id[0, v, u] == 0
    assert gb.depth[0, v, u] == pytest.approx(z, rel=1e-5)


@pytest.mark.gl
def test_gbuffer_matches_analytic_ray_plane_intersection():
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    cams = _odd_cameras()
    # a large tilted plane through q0 spanned by e1, e2 with uv = affine in the plane coordinates
    q0 = np.array([0.05, 0.1, -0.1])
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    e1 = np.array([1.0, 0.2, -0.15])
    e1 -= (e1 @ n) * n
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    s = 15.0
    corners = np.array([[-s, -s], [s, -s], [s, s], [-s, s]])
    verts = q0 + corners[:, :1] * e1 + corners[:, 1:] * e2
    uvs = (corners + s) / (2 * s) * 0.8 + 0.1  # u, v in [0.1, 0.9]
    mesh = MeshData(verts, [[0, 1, 2], [0, 2, 3]], uvs)
    gb = rasterize_gbuffer(mesh, cams)
    assert gb.uv.shape == (2, 64, 96, 2) and gb.face_id.shape == (2, 64, 96) and gb.depth.dtype == np.float32
    for i in range(len(cams)):
        assert gb.coverage[i].all()
        o, d = (t.double().numpy() for t in cams.rays(i))
        t = ((q0 - o) @ n) / (d @ n)
        p = o + t[..., None] * d
        a, b = (p - q0) @ e1, (p - q0) @ e2
        uv_ref = (np.stack([a, b], -1) + s) / (2 * s) * 0.8 + 0.1
        view = view_matrix(cams.c2w[i].double().numpy())
        depth_ref = -(p @ view[2, :3] + view[2, 3])
        assert np.abs(gb.uv[i] - uv_ref).max() < 1e-4
        assert np.abs(gb.depth[i] / depth_ref - 1).max() < 1e-4
        # a half-pixel shift would move uv by |duv/dpixel| / 2 -- make sure that is well above the tolerance
        assert np.abs(uv_ref[:, 1:] - uv_ref[:, :-1]).max() / 2 > 5e-4
        assert np.abs(uv_ref[1:] - uv_ref[:-1]).max() / 2 > 5e-4


def _quad(z, half, cx=0.0, cy=0.0):
    return np.array([[cx - half, cy - half, z], [cx + half, cy - half, z], [cx + half, cy + half, z],
                     [cx - half, cy + half, z]], float)


@pytest.mark.parametrize("near_first", [False, True])
@pytest.mark.gl
def test_face_id_nearest_wins_and_empty_is_minus_one(near_first):
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    far_q, near_q = _quad(-1.0, 1.0), _quad(0.5, 0.4)  # camera on +z looking down -z: z=0.5 is nearer
    quads = [near_q, far_q] if near_first else [far_q, near_q]
    verts = np.concatenate(quads)
    faces = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    pose = torch.eye(4)
    pose[2, 3] = 4.0  # at z = 4 looking down -z
    cams = Cameras(pose[None], 40.0, 40.0, 32.0, 32.0, 64, 64)
    gb = rasterize_gbuffer(MeshData(verts, faces, np.zeros((8, 2))), cams)
    near_ids = {0, 1} if near_first else {2, 3}
    far_ids = {2, 3} if near_first else {0, 1}
    # near quad: |x| <= 0.4 at depth 3.5 -> 4.6 px around the centre; far quad |x| <= 1 at depth 5 -> 8 px
    assert set(np.unique(gb.face_id[0, 29:35, 29:35])) <= near_ids
    assert set(np.unique(gb.face_id[0, 32, 25:27])) <= far_ids
    assert np.allclose(gb.depth[0, 30:34, 30:34], 3.5, rtol=1e-5)
    assert np.allclose(gb.depth[0, 32, 25:27], 5.0, rtol=1e-5)
    assert gb.face_id[0, 0, 0] == -1 and gb.face_id[0, 63, 63] == -1 and gb.face_id[0, 32, 50] == -1
    assert (gb.coverage[0] == (gb.face_id[0] >= 0)).all()
    assert np.isinf(gb.depth[0][~gb.coverage[0]]).all() and (gb.uv[0][~gb.coverage[0]] == 0).all()
    assert gb.coverage[0].sum() == pytest.approx(16 * 16, abs=2 * 16)


# ---------------------------------------------------------------------------------------------- playback
FRAG = """#version 330
uniform usampler2D u_index;
uniform sampler2D u_codebook;
uniform sampler2D u_unused;
uniform vec3 u_cam_pos;
in vec2 v_uv;
in vec3 v_world;
out vec4 f_color;
void main() {
    ivec2 size = textureSize(u_index, 0);
    ivec2 ij = clamp(ivec2(floor(v_uv * vec2(size))), ivec2(0), size - 1);
    uint k = texelFetch(u_index, ij, 0).r;
    f_color = vec4(texelFetch(u_codebook, ivec2(int(k), 0), 0).rgb, 1.0);
}
"""


def _bundle(frag=FRAG):
    rng = np.random.default_rng(0)
    index = rng.integers(0, 8, size=(3, 5)).astype(np.uint16)  # H=3, W=5 texels
    codebook = (rng.integers(0, 256, size=(1, 8, 3)) / 255.0).astype(np.float32)  # exact in 8 bits
    verts = np.array([[-1, -0.7, 0], [1, -0.7, 0], [1, 0.7, 0], [-1, 0.7, 0]], float)
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    mesh = MeshData(verts, [[0, 1, 2], [0, 2, 3]], uvs)
    return SimpleNamespace(mesh=mesh, fragment_shader=frag, background_color=(10 / 255, 200 / 255, 1.0),
                           textures={"u_index": index, "u_codebook": codebook,
                                     "u_unused": np.zeros((2, 2, 4), np.float32)})


def _front_camera(w=80, h=60):
    pose = look_at(torch.tensor([0.2, -0.3, 2.5]), torch.tensor([0.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
    return Cameras(pose[None].float(), 70.0, 64.0, 43.1, 28.4, w, h)


@pytest.mark.gl
def test_bundle_renderer_texel_fetch_colours_exact():
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.renderer import BundleRenderer

    bundle, cams = _bundle(), _front_camera()
    with BundleRenderer(bundle) as r:
        img = r.render(cams, 0)
    assert img.shape == (60, 80, 3) and img.dtype == np.float32
    gb = rasterize_gbuffer(bundle.mesh, cams)
    cov = gb.coverage[0]
    assert 0.2 < cov.mean() < 0.9
    assert np.array_equal(img[~cov], np.broadcast_to(np.float32(bundle.background_color), img[~cov].shape)) or \
        np.abs(img[~cov] - np.float32(bundle.background_color)).max() <= 0.5 / 255
    index, codebook = bundle.textures["u_index"], bundle.textures["u_codebook"]
    x = gb.uv[0] * np.array([index.shape[1], index.shape[0]])
    safe = cov & (np.abs(x - np.round(x)) > 1e-3).all(-1)  # away from texel borders
    ij = np.clip(np.floor(x).astype(int), 0, [index.shape[1] - 1, index.shape[0] - 1])
    expected = codebook[0, index[ij[..., 1], ij[..., 0]]]
    assert safe.sum() > 0.9 * cov.sum()
    assert np.abs(img[safe] - expected[safe]).max() <= 0.5 / 255
    # the image is upright: the bottom-left texel (v = 0, u = 0) is at the image's lower-left
    v_low, u_low = np.argwhere(safe & (ij[..., 0] == 0) & (ij[..., 1] == 0)).mean(0)
    v_high, u_high = np.argwhere(safe & (ij[..., 0] == 4) & (ij[..., 1] == 2)).mean(0)
    assert v_low > v_high and u_low < u_high


@pytest.mark.gl
def test_bundle_renderer_camera_uniform_and_timing():
    from neuras_distill.playback.renderer import BundleRenderer

    frag = """#version 330
uniform vec3 u_cam_pos;
in vec2 v_uv;
in vec3 v_world;
out vec4 f_color;
void main() { f_color = vec4(abs(u_cam_pos) / 4.0, 1.0); }
"""
    bundle = _bundle(frag)
    bundle.textures = {"u_index": bundle.textures["u_index"]}  # sampler absent from the shader: skipped
    cams = _front_camera(64, 48)
    with BundleRenderer(bundle) as r:
        img = r.render(cams, 0)
        centre = img[24, 32]
        assert np.abs(centre - np.abs(cams.c2w[0, :3, 3].numpy()) / 4.0).max() <= 1.0 / 255
        stats = r.time_frames(cams, warmup=1, frames=3)
    assert stats["frames"] == 3 and stats["resolution"] == [64, 48]
    assert math.isfinite(stats["fps"]) and stats["fps"] > 0 and stats["median_ms"] > 0
    assert stats["p90_ms"] >= stats["median_ms"]
    assert stats["pipelined_ms"] > 0 and stats["pipelined_fps"] == pytest.approx(1000.0 / stats["pipelined_ms"])
    # llvmpipe's timer queries time the submission, not the rasterizing: no GPU time is claimed for it
    from neuras_distill.playback.context import gl_info, software_gl
    assert (stats["gpu_median_ms"] is None) == software_gl(gl_info()["renderer"])


@pytest.mark.gl
def test_render_orbit_frames_writes_pngs(tmp_path):
    from PIL import Image

    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.viewer import render_orbit_frames

    bundle = _bundle()
    cams = Cameras.orbit([0, 0, 0], 2.5, 3, width=40, height=30, up_axis=1, elevation_deg=10.0)
    paths = render_orbit_frames(bundle, cams, tmp_path / "orbit")
    assert [p.name for p in paths] == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    with BundleRenderer(bundle) as r:
        ref = r.render(cams, 1)
    png = np.asarray(Image.open(paths[1]).convert("RGB"), np.float32) / 255.0
    assert png.shape == (30, 40, 3) and np.abs(png - ref).max() <= 0.5 / 255


def test_context_failure_is_glunavailable_with_reason(monkeypatch):
    from neuras_distill.playback import context

    moderngl = pytest.importorskip("moderngl")

    def boom(*args, **kwargs):
        raise Exception("libEGL.so.1: cannot open shared object file")

    monkeypatch.setattr(moderngl, "create_context", boom)
    monkeypatch.setattr(context, "_cache", {"pid": None, "ctx": None, "error": None})
    with pytest.raises(context.GLUnavailable, match="libEGL.so.1.*libegl1"):
        context.get_context()
    ok, reason = context.gl_available()
    assert not ok and "EGL backend" in reason


def test_playback_modules_import_without_moderngl():
    import subprocess
    import sys

    code = ("import sys, neuras_distill.playback.renderer, neuras_distill.playback.rasterize, "
            "neuras_distill.playback.viewer, neuras_distill.playback.context; "
            "assert 'moderngl' not in sys.modules, 'moderngl imported eagerly'")
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.gl
def test_render_orbit_frames_cli_form_frames_the_mesh(tmp_path):
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.viewer import orbit_cameras_for, render_orbit_frames

    bundle = _bundle()
    paths = render_orbit_frames(bundle, tmp_path / "o", frames=2, width=32, height=24)
    assert len(paths) == 2 and all(p.exists() for p in paths)
    gb = rasterize_gbuffer(bundle.mesh, orbit_cameras_for(bundle.mesh, 4, 32, 24, elevation_deg=60.0))
    assert gb.coverage.any(axis=(1, 2)).all()  # every view sees the quad
    assert not gb.coverage[:, [0, -1], :].any() and not gb.coverage[:, :, [0, -1]].any()  # and it fits the frame


@pytest.mark.gl
def test_back_faces_are_culled_only_when_asked():
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    verts = _quad(0.0, 1.0)
    facing = MeshData(verts, [[0, 1, 2], [0, 2, 3]], np.zeros((4, 2)))  # counter-clockwise seen from +z
    away = MeshData(verts, [[0, 2, 1], [0, 3, 2]], np.zeros((4, 2)))    # the same quad, wound the other way
    pose = torch.eye(4)
    pose[2, 3] = 4.0
    cams = Cameras(pose[None], 40.0, 40.0, 16.0, 16.0, 32, 32)
    assert rasterize_gbuffer(facing, cams, cull_back_faces=True).coverage[0, 16, 16]
    assert not rasterize_gbuffer(away, cams, cull_back_faces=True).coverage.any()
    assert rasterize_gbuffer(away, cams, cull_back_faces=False).coverage[0, 16, 16]
