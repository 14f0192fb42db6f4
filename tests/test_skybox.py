"""Neural skyboxes: layer geometry and validation, GLSL parity with the torch forward pass through the real
BundleRenderer, bundle round trip, and float32 precision for scenes far from the world origin."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neuras_distill.bake.bundle import bake, load_bundle
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.skybox import SkyboxGround, SkyboxLayers, SkyboxModel, plan_layers
from neuras_distill.render.cameras import Cameras, look_at

pytestmark = pytest.mark.usefixtures("one_torch_thread")
needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true


def _unit(v):
    v = torch.as_tensor(v, dtype=torch.float32)
    return v / v.norm(dim=-1, keepdim=True)


def test_exit_points_land_on_the_right_face_and_texel():
    layers = SkyboxLayers(center=(10.0, 20.0, 30.0), half_sizes=[2.0, 8.0], resolution=4)
    h, w = layers.atlas_size
    assert (h, w) == (16, 12)
    o = torch.zeros(6, 3)
    d = torch.tensor([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=torch.float32)
    uv = layers.atlas_uv(o, d)                                   # straight out of each face's centre
    for layer in range(2):
        for face in range(6):
            col, row = face % 3, 2 * layer + face // 3
            assert uv[layer, face].tolist() == pytest.approx([(col * 4 + 2) / 12, (row * 4 + 2) / 16])
    # a corner-bound ray is clamped half a texel inside its face (bilinear never reads the next face)
    uv = layers.atlas_uv(torch.zeros(1, 3), _unit([[1.0, 0.999, 0.999]]))
    x, y = uv[0, 0, 0] * 12, uv[0, 0, 1] * 16
    assert 0.5 <= float(x) <= 3.5 and 0.5 <= float(y) <= 3.5
    # an off-centre origin: the hit is where the ray really leaves the cube
    o = torch.tensor([[1.0, 0.5, -0.25]])
    d = _unit([[0.3, 1.0, 0.2]])
    t = (2.0 - 0.5) / float(d[0, 1])
    hit = o[0] + t * d[0]
    uv = layers.atlas_uv(o, d)[0, 0]
    a, b = float(hit[2]) / 2.0, float(hit[0]) / 2.0           # face +y (k=1): a = z, b = x
    assert float(uv[0]) * 12 == pytest.approx(2 * 4 + (a * 0.5 + 0.5) * 4, abs=1e-4)   # face 2: col 2, row 0
    assert float(uv[1]) * 16 == pytest.approx((b * 0.5 + 0.5) * 4, abs=1e-4)
    # axis-aligned directions with exact zeros stay finite
    assert torch.isfinite(layers.atlas_uv(torch.zeros(3, 3), torch.eye(3))).all()


def test_a_ray_that_meets_the_ground_first_lands_on_the_bottom_face_where_it_hit():
    """Floors at z = -1 (layer 0) and -3 (layer 1), z up: a ray going down meets the floor inside the cube and is
    stored on face -z (5) at the hit's in-face coordinates (a = x, b = y); a level ray and one that leaves through a
    wall first are unchanged; the floors round-trip through JSON and must lie below the cameras."""
    ground = SkyboxGround([0.0, 0.0, 2.0], [-1.0, -3.0])
    assert ground.axis == 2 and ground.face == 5 and ground.normal.tolist() == [0.0, 0.0, 1.0]
    layers = SkyboxLayers((0, 0, 0), [2.0, 8.0], 4, ground)
    cubes = SkyboxLayers((0, 0, 0), [2.0, 8.0], 4)
    o = torch.tensor([[0.2, -0.1, 0.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    d = _unit([[0.5, 0.25, -1.0], [1.0, 0.0, 0.0], [1.0, 0.0, -0.45]])
    uv, plain = layers.atlas_uv(o, d), cubes.atlas_uv(o, d)
    for layer, (h, r) in enumerate(((-1.0, 2.0), (-3.0, 8.0))):
        t = (h - 0.5) / float(d[0, 2])
        hit = o[0] + t * d[0]
        a, b = float(hit[0]) / r, float(hit[1]) / r                            # face -z (k = 2): a = x, b = y
        assert float(uv[layer, 0, 0]) * 12 == pytest.approx(2 * 4 + (a * 0.5 + 0.5) * 4, abs=1e-4)   # column 2
        assert float(uv[layer, 0, 1]) * 16 == pytest.approx((2 * layer + 1) * 4 + (b * 0.5 + 0.5) * 4, abs=1e-4)
    assert torch.equal(uv[:, 1], plain[:, 1])                                   # level: through the wall
    assert torch.equal(uv[0, 2], plain[0, 2])                                   # x = 2 comes before z = -1 (x = 2.2)
    assert not torch.equal(uv[1, 2], plain[1, 2])                               # z = -3 (x = 6.7) comes before x = 8
    back = SkyboxLayers.from_json(layers.to_json())
    assert back.ground.heights.tolist() == [-1.0, -3.0] and "ground" not in cubes.to_json()
    with pytest.raises(BadInputError, match="below the cameras"):
        layers.check_cameras(np.array([[0.0, 0.0, -1.5]]))
    with pytest.raises(BadInputError, match="one height per layer"):
        SkyboxLayers((0, 0, 0), [2.0, 8.0], 4, SkyboxGround([0, 0, 1], [-1.0]))


def test_layers_must_nest_and_enclose_the_cameras():
    aabb = np.array([[-1.0, -1, -1], [1, 1, 1]])
    cams = np.array([[0.0, 0, 0], [2.5, 0, 0]])
    layers = plan_layers(aabb, cams, num_layers=4)
    assert layers.half_sizes[0] >= 1.25 * 2.5 and np.all(np.diff(layers.half_sizes) > 0)
    assert layers.half_sizes[-1] == pytest.approx(16 * layers.half_sizes[0])
    ratios = layers.half_sizes[1:] / layers.half_sizes[:-1]
    assert np.allclose(ratios, ratios[0])                     # geometric spacing
    with pytest.raises(BadInputError, match="does not enclose every camera"):
        plan_layers(aabb, cams, near=2.0, far=50.0)
    with pytest.raises(BadInputError, match="must nest"):
        plan_layers(aabb, cams, near=50.0, far=10.0)
    with pytest.raises(BadInputError, match="must nest"):
        SkyboxLayers((0, 0, 0), [5.0, 5.0], 8)
    with pytest.raises(BadInputError, match="at least 1"):
        plan_layers(aabb, cams, num_layers=0)
    with pytest.raises(BadInputError, match="finite"):
        SkyboxLayers((0, 0, 0), [5.0, float("nan")], 8)


def test_outermost_layer_is_opaque_and_compositing_is_front_to_back():
    layers = SkyboxLayers((0, 0, 0), [3.0, 6.0], 4)
    sky = SkyboxModel(layers, feature_dim=4, num_codes=8, hidden=8)
    with torch.no_grad():
        sky.shader.alpha.weight.zero_()
        sky.shader.alpha.bias.fill_(math.log(0.25 / 0.75))   # inner layer 25% opaque
    d = _unit(torch.randn(50, 3, generator=torch.Generator().manual_seed(1)))
    o = torch.zeros(50, 3)
    rgb, _ = sky(o, d)
    uv = layers.atlas_uv(o, d)
    f, _ = sky.atlas.features(uv.reshape(-1, 2))
    c, _ = sky.shader(f, d.repeat(2, 1))
    c = c.view(2, 50, 3)
    assert torch.allclose(rgb, 0.25 * c[0] + 0.75 * c[1], atol=1e-6)


def _trained_like(layers, seed=0):
    torch.manual_seed(seed)
    sky = SkyboxModel(layers, feature_dim=6, num_codes=16, hidden=8)
    with torch.no_grad():
        sky.atlas.texture.data.normal_(0.0, 1.0)
        for p in sky.shader.parameters():
            p.normal_(0.0, 0.8)
    sky.atlas.start_vq()
    sky.eval()
    return sky


def _tiny_mesh_model():
    model = NeuralTextureModel(8, 8, feature_dim=4, num_codes=8, use_viewdir=False)
    model.start_vq()
    model.eval()
    v = np.array([[-0.2, -0.2, 0], [0.2, -0.2, 0], [0.2, 0.2, 0], [-0.2, 0.2, 0]], np.float32)
    return model, MeshData(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), (v[:, :2] + 0.5).astype(np.float32))


def _cameras(center, n=3, width=96, height=54):
    center = torch.as_tensor(center, dtype=torch.float32)
    eyes = [center + torch.tensor(e) for e in ([0.5, -0.3, 0.2], [-0.4, 0.2, -0.1], [0.1, 0.4, 0.3])][:n]
    targets = [center + torch.tensor(t) for t in ([3.0, 1.0, 0.5], [-1.0, -3.0, 2.0], [0.3, 0.2, -4.0])][:n]
    c2w = torch.stack([look_at(e, t, torch.tensor([0.0, 0.0, 1.0])) for e, t in zip(eyes, targets)])
    f = 0.5 * width / math.tan(math.radians(35))
    return Cameras(c2w, f, f, width / 2, height / 2, width, height)


@needs_gl
@pytest.mark.parametrize("ground", [None, SkyboxGround([0.05, -0.03, 1.0], [-0.6, -1.0, -1.5])],
                         ids=["cubes", "on the ground"])
def test_sky_pass_matches_torch_through_the_bundle_renderer(tmp_path, ground):
    from neuras_distill.playback.renderer import BundleRenderer

    center = np.array([0.25, -0.5, 0.75])
    layers = SkyboxLayers(center, [2.0, 5.0, 12.0], 8, ground)
    sky = _trained_like(layers)
    model, mesh = _tiny_mesh_model()
    cams = _cameras(center)
    bundle = load_bundle(bake(model, mesh, (0, 0, 0), skybox=sky).save(tmp_path / "b"))
    assert bundle.has_skybox and "vec3 u_sky_origin" in bundle.sky_fragment_shader
    assert ("GROUND_H" in bundle.sky_fragment_shader) == (ground is not None)
    if ground is not None:                                                 # the third camera looks down at it
        o, d = cams.rays(2)
        floor = (layers.atlas_uv(layers.relative(o.reshape(-1, 3)), d.reshape(-1, 3))
                 != SkyboxLayers(center, [2.0, 5.0, 12.0], 8).atlas_uv(layers.relative(o.reshape(-1, 3)),
                                                                       d.reshape(-1, 3))).any(-1)
        assert floor.float().mean() > 0.3
    with BundleRenderer(bundle) as player:
        for i in range(len(cams)):
            gl = player.render(cams, i)
            no_sky = player.render(cams, i, skybox=False)
            covered = (no_sky != 0).any(-1)                                # the mesh (clear colour is black)
            o, d = cams.rays(i)
            with torch.no_grad():
                ref, _ = sky(layers.relative(o.reshape(-1, 3)), d.reshape(-1, 3))
            ref = ref.view(cams.height, cams.width, 3).numpy()
            assert covered.mean() < 0.5
            mse = float(np.mean((gl - ref)[~covered] ** 2))
            assert 10 * math.log10(1.0 / max(mse, 1e-12)) > 40.0, i
            assert ref.std() > 0.02                                        # not a flat colour
            assert np.array_equal(gl[covered], no_sky[covered])            # the mesh is drawn over the sky


def test_bundle_without_skybox_files_is_refused(tmp_path):
    layers = SkyboxLayers((0, 0, 0), [2.0, 5.0], 4)
    model, mesh = _tiny_mesh_model()
    path = bake(model, mesh, (0, 0, 0), skybox=_trained_like(layers)).save(tmp_path / "b")
    (path / "sky.frag").unlink()
    with pytest.raises(BadInputError, match="sky.frag"):
        load_bundle(path)


@needs_gl
def test_far_from_the_world_origin_plays_like_at_the_origin(tmp_path):
    """The same scene at (3 km, -2 km, 50 m): mesh and skybox render as at the origin (float32 safe)."""
    from neuras_distill.playback.renderer import BundleRenderer

    images = []
    for offset in (np.zeros(3), np.array([3000.0, -2000.0, 50.0])):
        layers = SkyboxLayers(offset, [2.0, 6.0], 8)
        sky = _trained_like(layers, seed=3)
        model, mesh = _tiny_mesh_model()
        with torch.no_grad():
            model.texture.data.normal_(0.0, 1.0)
        model.start_vq()
        bundle = bake(model, mesh, (0, 0, 0), skybox=sky, origin=offset)
        eye = torch.tensor(offset + [0.05, 0.3, 0.9], dtype=torch.float64)
        c2w = look_at(eye, torch.tensor(offset, dtype=torch.float64), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
        cams = Cameras(c2w[None].float(), 80.0, 80.0, 48.0, 27.0, 96, 54)
        with BundleRenderer(bundle) as player:
            images.append(player.render(cams, 0))
            assert (player.render(cams, 0, skybox=False) != 0).any(-1).mean() > 0.05   # the quad is in view
    assert np.abs(images[0] - images[1]).max() <= 2.0 / 255.0
