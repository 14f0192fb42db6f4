"""Two-layer meshes (``MeshData.core_faces``): the core wins every pixel it covers, the shell fills the rest.

A core sphere (radius 0.4) inside a shell sphere (radius 0.5): the shell is nearer at every pixel, so a plain
depth test would show only the shell. Checked on the G-buffer (face ids, depth), on bundle playback against the
torch reference, through a bundle's save / load, and that a single-layer mesh renders bit for bit as before.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from neuras_distill.bake.bundle import bake, load_bundle
from neuras_distill.config import TrainConfig
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.render.cameras import Cameras

gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true
pytestmark = [pytest.mark.usefixtures("one_torch_thread")]

R_CORE, R_SHELL = 0.4, 0.5

# The stages' sources before the layers (the reference of "a single layer renders as before").
OLD_VERTEX_SHADER = """#version 330
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
OLD_GBUFFER_FRAGMENT_SHADER = """#version 330
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


def _sphere(radius: float, subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    trimesh = pytest.importorskip("trimesh")
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(s.vertices, np.float32)
    uv = 0.5 + 0.45 * v[:, :2] / radius          # any uvs in [0, 1] will do: the reference reads the same G-buffer
    return v, np.asarray(s.faces, np.int32), uv.astype(np.float32)


def two_spheres(core_faces: bool = True) -> MeshData:
    """Core sphere then shell sphere in one mesh; ``core_faces=False`` gives the same faces as one layer."""
    vc, fc, uc = _sphere(R_CORE)
    vs, fs, us = _sphere(R_SHELL, 2)
    return MeshData(np.concatenate([vc, vs]), np.concatenate([fc, fs + len(vc)]), np.concatenate([uc, us]),
                    core_faces=len(fc) if core_faces else None)


def part(mesh: MeshData, layer: int) -> MeshData:
    """The core (0) or the shell (1) of ``mesh`` alone, as a single-layer mesh on the same vertices."""
    faces = mesh.faces[:mesh.core_faces] if layer == 0 else mesh.faces[mesh.core_faces:]
    return MeshData(mesh.vertices, faces, mesh.uvs)


def cameras(n: int = 3, size: int = 64) -> Cameras:
    return Cameras.orbit([0.0, 0.0, 0.0], 2.0, n, width=size, height=size, fov_deg=40.0, elevation_deg=20.0,
                         phase_deg=10.0)


def ray_geometry(cams: Cameras, i: int) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) distance of each pixel's ray from the spheres' centre, and (H, W) view depth of its hit on the
    core sphere (nan where it misses)."""
    o, d = (t.double().numpy() for t in cams.rays(i))
    od = (o * d).sum(-1)
    perp = np.sqrt(np.maximum((o * o).sum(-1) - od ** 2, 0.0))
    t = -od - np.sqrt(np.maximum(R_CORE ** 2 - perp ** 2, 0.0))
    forward = -cams.c2w[i, :3, 2].double().numpy()
    depth = np.where(perp < R_CORE, t * (d @ forward), np.nan)
    return perp, depth


def make_model(seed: int = 0, mesh_layers: int = 1, core_viewdir=None, shell_hidden=None) -> NeuralTextureModel:
    from test_bake import make_model as random_model

    return random_model(h=16, w=16, seed=seed, use_facing=True, mesh_layers=mesh_layers, core_viewdir=core_viewdir,
                        shell_hidden=shell_hidden)


# ---------------------------------------------------------------------------------------------- no GL needed
def test_draw_calls_of_each_layout():
    from neuras_distill.playback.rasterize import CORE_LAYER, SHELL_LAYER, SINGLE_LAYER, mesh_layers

    mesh = two_spheres()
    f, c = mesh.num_faces, mesh.core_faces
    assert mesh_layers(mesh) == [(CORE_LAYER, 0, c), (SHELL_LAYER, c, f - c)]      # core first
    assert mesh_layers(two_spheres(False)) == [(SINGLE_LAYER, 0, f)]
    assert mesh_layers(MeshData(mesh.vertices, mesh.faces, core_faces=0)) == [(SHELL_LAYER, 0, f)]
    assert mesh_layers(MeshData(mesh.vertices, mesh.faces, core_faces=f)) == [(CORE_LAYER, 0, f)]
    assert mesh_layers(MeshData(np.zeros((0, 3)), np.zeros((0, 3)))) == []


def test_bundle_round_trips_core_faces_and_reads_old_bundles(tmp_path):
    from neuras_distill.playback.shaders import VERTEX_SHADER

    m, mesh = make_model(), two_spheres()
    b = bake(m, mesh, (0.1, 0.2, 0.3), vertex_shader=VERTEX_SHADER)
    assert b.mesh.core_faces == mesh.core_faces and b.manifest["core_faces"] == mesh.core_faces
    back = load_bundle(b.save(tmp_path / "two"))
    assert back.mesh.core_faces == mesh.core_faces and isinstance(back.mesh.core_faces, int)
    assert np.array_equal(back.mesh.faces, mesh.faces)
    assert back.vertex_shader == VERTEX_SHADER and "u_layer" in back.vertex_shader
    saved = json.loads((tmp_path / "two" / "manifest.json").read_text())
    assert saved["core_faces"] == mesh.core_faces and saved["format_version"] == 3   # old readers refuse it

    single = bake(m, two_spheres(False), (0.1, 0.2, 0.3))
    back = load_bundle(single.save(tmp_path / "one"))
    saved = json.loads((tmp_path / "one" / "manifest.json").read_text())
    assert back.mesh.core_faces is None and saved["core_faces"] is None and saved["format_version"] == 2

    # a bundle written before the layers has no key: one layer
    del saved["core_faces"]
    (tmp_path / "one" / "manifest.json").write_text(json.dumps(saved))
    assert load_bundle(tmp_path / "one").mesh.core_faces is None

    for bad in (-1, mesh.num_faces + 1, 2.5, "7", True):
        saved["core_faces"] = bad
        (tmp_path / "one" / "manifest.json").write_text(json.dumps(saved))
        with pytest.raises(BadInputError, match="core_faces"):
            load_bundle(tmp_path / "one")
    with pytest.raises(BadInputError, match="core_faces"):
        bake(m, MeshData(mesh.vertices, mesh.faces, mesh.uvs, core_faces=mesh.num_faces + 1), (0, 0, 0))


# ---------------------------------------------------------------------------------------------- G-buffer
@gl
@pytest.mark.gl
@pytest.mark.parametrize("cull", [True, False])
def test_core_wins_inside_its_silhouette_shell_fills_the_annulus(cull):
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    mesh, cams = two_spheres(), cameras()
    c = mesh.core_faces
    gb = rasterize_gbuffer(mesh, cams, cull_back_faces=cull)
    plain = rasterize_gbuffer(two_spheres(False), cams, cull_back_faces=cull)   # one layer: the shell hides all
    for i in range(len(cams)):
        perp, core_depth = ray_geometry(cams, i)
        inside, annulus, outside = perp < 0.95 * R_CORE, (perp > 1.05 * R_CORE) & (perp < 0.95 * R_SHELL), perp > 1.05 * R_SHELL
        assert inside.sum() > 300 and annulus.sum() > 150
        face = gb.face_id[i]
        assert (face[inside] >= 0).all() and (face[inside] < c).all()                 # (1) core inside
        assert (face[annulus] >= c).all() and (face[annulus] < mesh.num_faces).all()  # (1) shell around it
        assert (face[outside] == -1).all()
        assert (plain.face_id[i][inside] >= c).all()       # the shell is nearer: depth alone would show it
        # (2) the true view depth of the core, not of the shell (the icosphere lies at most ~0.5% inside)
        err = np.abs(gb.depth[i][inside] - core_depth[inside])
        assert err.max() < 0.01, err.max()
        assert (plain.depth[i][inside] < gb.depth[i][inside] - 0.02).all()

    # exactly what each layer alone gives: the core where it covers, else the shell with global face ids
    core, shell = rasterize_gbuffer(part(mesh, 0), cams, cull_back_faces=cull), \
        rasterize_gbuffer(part(mesh, 1), cams, cull_back_faces=cull)
    cov = core.coverage
    assert np.array_equal(gb.face_id, np.where(cov, core.face_id, np.where(shell.coverage, shell.face_id + c, -1)))
    assert np.array_equal(gb.depth, np.where(cov, core.depth, shell.depth))
    assert np.array_equal(gb.uv, np.where(cov[..., None], core.uv, shell.uv))


@gl
@pytest.mark.gl
def test_priority_comes_from_the_layer_not_the_draw_order(monkeypatch):
    """(3) Shell drawn first, core second: the same G-buffer. The shell is nearer everywhere, so with the plain
    depth test it would win whichever order; the remapped depth makes the core win in both."""
    from neuras_distill.playback import rasterize

    mesh, cams = two_spheres(), cameras()
    forward = rasterize.rasterize_gbuffer(mesh, cams)
    normal_order = rasterize.mesh_layers
    monkeypatch.setattr(rasterize, "mesh_layers", lambda m: normal_order(m)[::-1])
    assert [layer for layer, _, _ in rasterize.mesh_layers(mesh)] == [rasterize.SHELL_LAYER, rasterize.CORE_LAYER]
    reversed_ = rasterize.rasterize_gbuffer(mesh, cams)
    for name in ("face_id", "depth", "uv", "coverage"):
        assert np.array_equal(getattr(forward, name), getattr(reversed_, name)), name
    assert (forward.face_id[forward.coverage] < mesh.core_faces).mean() > 0.5


@gl
@pytest.mark.gl
def test_single_layer_is_bit_for_bit_the_pre_layer_output(monkeypatch):
    """(5) core_faces None: G-buffer and playback equal to the stages' sources before the layers, on a mesh
    with overlapping surfaces (both spheres as one layer) and on the bunny."""
    trimesh = pytest.importorskip("trimesh")
    from neuras_distill.playback import rasterize, renderer
    from neuras_distill.scenes.synthetic import BUNNY_OBJ

    bunny = trimesh.load(BUNNY_OBJ, force="mesh")
    b = MeshData(bunny.vertices, bunny.faces)
    b.vertices -= b.vertices.mean(0)
    b.vertices *= np.float32(0.45 / np.abs(b.vertices).max())
    meshes = [two_spheres(False), b]
    cams = cameras(4, 96)
    new = [rasterize.rasterize_gbuffer(m, cams, cull_back_faces=cull) for m in meshes for cull in (True, False)]
    from test_bake import make_model as random_model

    m = random_model(h=16, w=16)     # no facing input: it reads v_normal, which the old vertex stage lacks
    bundle = bake(m, meshes[0], (0.2, 0.3, 0.4))
    with renderer.BundleRenderer(bundle) as r:
        new_img = [r.render(cams, i) for i in range(len(cams))]

    monkeypatch.setattr(rasterize, "VERTEX_SHADER", OLD_VERTEX_SHADER)
    monkeypatch.setattr(rasterize, "GBUFFER_FRAGMENT_SHADER", OLD_GBUFFER_FRAGMENT_SHADER)
    monkeypatch.setattr(renderer, "VERTEX_SHADER", OLD_VERTEX_SHADER)
    old = [rasterize.rasterize_gbuffer(m, cams, cull_back_faces=cull) for m in meshes for cull in (True, False)]
    with renderer.BundleRenderer(bundle) as r:
        assert "u_layer" not in r.program
        old_img = [r.render(cams, i) for i in range(len(cams))]
    for a, o in zip(new, old):
        assert a.coverage.mean() > 0.1
        for name in ("face_id", "depth", "uv"):
            assert np.array_equal(getattr(a, name), getattr(o, name)), name
    for a, o in zip(new_img, old_img):
        assert np.array_equal(a, o)


# ---------------------------------------------------------------------------------------------- playback
@gl
@pytest.mark.gl
@pytest.mark.parametrize("shaders,core_viewdir,shell_hidden", [(1, None, None), (2, None, None), (2, False, 28)])
def test_playback_of_a_two_layer_bundle_matches_the_torch_reference(tmp_path, shaders, core_viewdir, shell_hidden):
    """(4) The saved and reloaded bundle plays, pixel for pixel, the torch forward pass on the two-layer
    G-buffer (view direction and facing cosine on: the facing input reads the global face id's normal); with
    a shader per layer, each layer's program runs its own MLP (also when the core's takes no direction, its
    facing weight then reads lane 3 of the view vector, and when the shell's is wider than the core's)."""
    from neuras_distill.pipeline.evaluate import gl_torch_parity
    from neuras_distill.playback.rasterize import rasterize_gbuffer
    from neuras_distill.playback.renderer import BundleRenderer
    from neuras_distill.playback.shaders import VERTEX_SHADER
    from neuras_distill.playback.viewer import render_orbit_frames

    m, mesh = make_model(mesh_layers=shaders, core_viewdir=core_viewdir, shell_hidden=shell_hidden), two_spheres()
    assert m.shaders[0].use_viewdir == (core_viewdir is None) and m.shaders[-1].use_viewdir
    assert m.shaders[-1].hidden == (shell_hidden or m.hidden)
    bg = np.float32([0.1, 0.2, 0.3])
    bundle = load_bundle(bake(m, mesh, bg, vertex_shader=VERTEX_SHADER).save(tmp_path / "b"))
    assert bundle.manifest["shaders"] == shaders
    assert bundle.manifest["shell_mlp_hidden"] == (None if shaders == 1 else shell_hidden or m.hidden)
    cams = cameras(3, 80)
    if shaders == 2:         # the shell's own MLP: the core's MLP on every pixel (as one shader would) is far off
        core_everywhere = bake(m, mesh, bg)
        core_everywhere.fragment_shader = core_everywhere.fragment_shader.replace("MESH_LAYER == 1", "0")
        with BundleRenderer(core_everywhere) as r:
            wrong = gl_torch_parity(m, mesh, cams[0], r.render(cams, 0), bg, rasterize_gbuffer)
        assert wrong < 40.0, wrong
    one_layer = load_bundle(bake(make_model(), two_spheres(False), bg).save(tmp_path / "one"))
    with BundleRenderer(bundle) as r, BundleRenderer(one_layer) as plain:
        for i in range(len(cams)):
            image = r.render(cams, i)
            psnr = gl_torch_parity(m, mesh, cams[i], image, bg, rasterize_gbuffer)
            assert psnr > 50.0, (i, psnr)             # 8-bit framebuffer: ~59 dB when identical
            wrong = gl_torch_parity(m, mesh, cams[i], plain.render(cams, i), bg, rasterize_gbuffer)
            assert wrong < psnr - 10.0, (psnr, wrong)  # showing the shell over the core is far off
        stats = r.time_frames(cams, warmup=1, frames=2)
        assert stats["median_ms"] > 0
    # the orbit viewer plays the same layers
    paths = render_orbit_frames(bundle, cams, tmp_path / "orbit")
    from PIL import Image

    png = np.asarray(Image.open(paths[0]).convert("RGB"), np.float32) / 255.0
    with BundleRenderer(bundle) as r:
        assert np.abs(png - r.render(cams, 0)).max() <= 0.5 / 255


@gl
@pytest.mark.gl
def test_the_depth_prepass_shades_the_same_pixels(tmp_path):
    """The depth-only prepass (on by default for two-layer meshes on a rasterizing GPU) changes no pixel: the
    same vertex stage gives the same depths, and the shading pass keeps only the fragment that won them."""
    from neuras_distill.playback.renderer import BundleRenderer

    bg = np.float32([0.1, 0.2, 0.3])
    cams = cameras(3, 80)
    for mesh in (two_spheres(), two_spheres(False)):
        bundle = bake(make_model(mesh_layers=2 if mesh.core_faces is not None else 1), mesh, bg)
        with BundleRenderer(bundle, depth_prepass=True) as pre, BundleRenderer(bundle, depth_prepass=False) as one:
            assert pre.depth_vao is not None and one.depth_vao is None
            for i in range(len(cams)):
                a, b = pre.render(cams, i), one.render(cams, i)
                assert (a != b).any(axis=-1).mean() < 1e-3       # ties between coplanar faces at most
                assert (np.abs(a - bg).max(axis=-1) > 2 / 255).mean() > 0.05   # the mesh is in view
        with BundleRenderer(bundle) as default:                  # llvmpipe here: no prepass
            assert default.depth_vao is None


@gl
@pytest.mark.gl
def test_invalid_core_faces_is_refused():
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    mesh = two_spheres()
    for bad in (-1, mesh.num_faces + 1, 1.5):
        with pytest.raises(ValueError, match="core_faces"):
            rasterize_gbuffer(MeshData(mesh.vertices, mesh.faces, core_faces=bad), cameras(1, 16))


def test_layers_split_and_join_back():
    mesh = two_spheres()
    core, shell = mesh.layers()
    assert core.num_faces == mesh.core_faces and shell.num_faces == mesh.num_faces - mesh.core_faces
    assert np.allclose(np.linalg.norm(core.vertices, axis=1), R_CORE, atol=0.01)
    assert np.allclose(np.linalg.norm(shell.vertices, axis=1), R_SHELL, atol=0.01)
    joined = MeshData.two_layers(core, shell)
    assert joined.core_faces == mesh.core_faces
    assert np.array_equal(joined.vertices[joined.faces], mesh.vertices[mesh.faces])
    assert two_spheres(core_faces=False).layers()[0].num_faces == mesh.num_faces


def test_unwrap_keeps_the_layers_and_gives_the_shell_the_texels_of_its_layout():
    """Faces keep their order through xatlas (so ``core_faces`` still splits the layers), and a shell laid out
    at half scale gets a quarter of the uv area per unit surface area that the core gets."""
    from neuras_distill.geometry.unwrap import unwrap

    mesh = two_spheres()
    n_core_vertices = int(mesh.faces[:mesh.core_faces].max()) + 1
    layout = mesh.vertices.copy()
    layout[n_core_vertices:] *= 0.5
    out = unwrap(MeshData(mesh.vertices, mesh.faces, None, core_faces=mesh.core_faces), resolution=256,
                 timeout_s=60, layout_vertices=layout)
    assert out.core_faces == mesh.core_faces
    assert np.allclose(out.vertices[out.faces], mesh.vertices[mesh.faces])     # same faces, same order
    core, shell = out.layers()
    density = [layer.uv_area() / (4 * np.pi * r ** 2) for layer, r in ((core, R_CORE), (shell, R_SHELL))]
    assert density[1] / density[0] == pytest.approx(0.25, rel=0.15), density


def test_a_shader_per_layer_picks_by_the_layer_column():
    """view_inputs appends the layer (face id >= core_faces) after the facing cosine; the model runs the core's
    MLP on layer-0 rows and the shell's on layer-1 rows, and fit trains both."""
    import torch

    from neuras_distill.neural.model import view_inputs
    from neuras_distill.neural.train import fit
    from neuras_distill.neural.train_batches import TrainingPixels

    normals = np.float32([[[0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0]]])      # per pixel (GBuffer.normal)
    dirs = np.float32([[[0, 0, -1], [0, 0, -1], [0, 0, -1], [0, 0, -1]]])
    face_id = np.array([[-1, 0, 1, 2]])
    inputs = view_inputs(dirs, face_id, normals, True, core_faces=2)
    assert inputs.shape == (1, 4, 5)
    np.testing.assert_array_equal(inputs[0, :, 3], [0, 1, 0, 0])            # |n . d|, 0 where uncovered
    np.testing.assert_array_equal(inputs[0, :, 4], [0, 0, 0, 1])            # face 2 is the shell's

    m = make_model(mesh_layers=2)
    assert m.view_columns == 5
    uv = torch.rand(6, 2)
    d = torch.cat([torch.nn.functional.normalize(torch.randn(6, 3), dim=1), torch.rand(6, 1),
                   torch.tensor([[0.0], [1.0], [0.0], [1.0], [1.0], [0.0]])], dim=1)
    with torch.no_grad():
        rgb, _ = m(uv, d)
        f, _ = m.features(uv)
        core, shell = m.shaders[0](f, d[:, :4]), m.shaders[1](f, d[:, :4])
    expected = torch.where(d[:, 4:5] > 0.5, shell, core)
    torch.testing.assert_close(rgb, expected)
    assert (core - shell).abs().max() > 0.05                                 # the two MLPs differ

    blind = make_model(mesh_layers=2, core_viewdir=False)      # the core ignores the direction, the shell not
    turned = d.clone()
    turned[:, :3] = -turned[:, :3]
    with torch.no_grad():
        a, b = blind(uv, d)[0], blind(uv, turned)[0]
    core_rows = d[:, 4] < 0.5
    torch.testing.assert_close(a[core_rows], b[core_rows])
    assert (a[~core_rows] - b[~core_rows]).abs().max() > 1e-3
    with pytest.raises(ValueError, match="two-layer"):
        NeuralTextureModel(4, 4, mesh_layers=1, core_viewdir=False)

    before = [p.detach().clone() for p in m.shaders[1].parameters()]
    h = w = 8
    gen = np.random.default_rng(0)
    layer = np.zeros((1, h, w, 1), np.float32)
    layer[:, :, w // 2:] = 1.0
    view = np.concatenate([np.tile(np.float32([0, 0, -1, 1]), (1, h, w, 1)), layer], axis=-1)
    fit(m, TrainingPixels(gen.random((1, h, w, 2), dtype=np.float32), np.ones((1, h, w), bool), view,
                          gen.random((1, h, w, 3), dtype=np.float32)), steps=3, config=TrainConfig(batch_patches=2, patch=4),
        progress=False)
    assert any((p - q).abs().max() > 0 for p, q in zip(m.shaders[1].parameters(), before))


def test_the_core_drops_the_view_direction_only_at_the_colour_level_of_a_view_independent_field():
    """``choices.core_view_dependence``: a two-layer mesh whose core sits at the colour level of a field
    whose colour does not change with the view gets a core shader without the direction (and says so in
    ``left_out``); a view-dependent field, a surface-level core, a one-layer mesh or a forced setting keep it."""
    import torch

    from neuras_distill.config import DistillConfig, load_config
    from neuras_distill.pipeline.choices import Decisions, core_view_dependence

    class Field:
        def __init__(self, glossy: bool):
            self.glossy = glossy

        def radiance(self, x, d):
            return torch.sigmoid(x + (2.0 * d if self.glossy else 0.0))

    mesh = two_spheres()
    mesh.stats = {"mc_colour_level_used": True}
    cfg = DistillConfig()
    record = Decisions()
    assert core_view_dependence(Field(False), mesh, cfg, True, record) is False
    assert [e["component"] for e in record.left_out()] == ["view direction of the core's shader"]
    record = Decisions()
    assert core_view_dependence(Field(True), mesh, cfg, True, record) is None and not record.items
    assert core_view_dependence(Field(False), mesh, cfg, False, record) is None
    surface = two_spheres()
    surface.stats = {"mc_colour_level_used": False}
    assert core_view_dependence(Field(False), surface, cfg, True, record) is None
    one = two_spheres(False)
    one.stats = {"mc_colour_level_used": True}
    assert core_view_dependence(Field(False), one, cfg, True, record) is None
    forced = load_config(overrides={"texture": {"view_dependence": "on"}})
    assert core_view_dependence(Field(False), mesh, forced, True, record) is None
    assert not record.items


def test_the_fringe_threshold_scales_with_the_training_views_width():
    """``choices.fringe_shell``: the same soft fringe, as a share of the view, gets the shell whatever width the
    teacher renders at (8 px at 640 wide: 4.8 px at 384); a fringe of 5.6 px is wide at 384 and narrow at 640."""
    from types import SimpleNamespace

    from neuras_distill.pipeline.choices import Decisions, fringe_shell
    from neuras_distill.pipeline.rules import fringe_width_pixels

    def disk(width: int, ramp_px: float) -> np.ndarray:
        """(1, H, W) opacity of a disk a third of the view wide whose edge fades over ``ramp_px`` pixels."""
        h = width * 9 // 16
        y, x = np.mgrid[:h, :width] + 0.5
        r = np.hypot(x - width / 2, y - h / 2)
        return np.clip((width / 6 - r) / ramp_px + 0.5, 0.0, 1.0)[None].astype(np.float32)

    constant = SimpleNamespace(constant=True)
    for width, ramp, kept in ((384, 6.2, True), (640, 6.2, False), (640, 10.0, True), (1280, 10.0, False)):
        opacity = disk(width, ramp)
        record = Decisions()
        assert fringe_shell("auto", opacity, constant, record) == kept, (width, ramp, fringe_width_pixels(opacity))
        assert bool(record.left_out()) == (not kept)
        if not kept:
            assert f"in views {width} wide" in record.left_out()[-1]["reason"]
