"""Tests for the embedded street scene (neuras_distill.scenes.street) and Cameras.lane_shifted.

Tolerances used below:
* SDF values at hand-computed points: 1e-4 m (float32 arithmetic on coordinates up to 40 m).
* |grad sdf| by central differences (h = 2 mm) at points within 0.1 m of a surface, approached from the air:
  at least 95 % within 0.05 of 1 (the rest sit where two primitives meet in a concave edge, where the
  min of exact SDFs has a kink and the difference quotient averages two unit gradients), and never above
  1.05 (the field never overstates a slope: a min of 1-Lipschitz functions is 1-Lipschitz).
* Origin offset (3000, -2000, 50): world coordinates in float32 carry ~1.2e-4 m of rounding at 3 km, so the
  SDF may differ by up to sqrt(3) * 1.2e-4 < 5e-4 m; colours by up to 0.01 (the softest texture edges are
  ~3 cm wide, so 0.1 mm of shift moves a colour by ~0.005 at worst), 2e-4 on average.
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from neuras_distill.errors import BadInputError
from neuras_distill.fields.base import check_field
from neuras_distill.fields.wrappers import SDFToDensityField
from neuras_distill.pipeline.rules import background_is_constant
from neuras_distill.render.cameras import Cameras, look_at
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.street import AABB, LANE_Y, StreetField, make_street
from neuras_distill.scenes.synthetic import SCENE_BETA, SCENES, make_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ORIGIN = (3000.0, -2000.0, 50.0)


@pytest.fixture(scope="module")
def field() -> StreetField:
    return StreetField()


def _near_surface_points(field: StreetField, n: int, seed: int, band: float = 0.1) -> torch.Tensor:
    """Points within ``band`` of a surface, on the air side: random air points projected onto the surface
    (three Newton steps along the normal) and pushed back out by U(0, band)."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = field.aabb[0], field.aabb[1]
    x = lo + torch.rand(4 * n, 3, generator=g) * (hi - lo)
    x = x[field.geometry(x) > 0][:n]
    for _ in range(3):
        x = x - field.normal(x) * field.geometry(x)[:, None]
    return x + torch.rand(x.shape[0], 1, generator=g) * band * field.normal(x)


# ---------------------------------------------------------------------------------------------- geometry
def test_sdf_at_known_points(field):
    pts = torch.tensor([
        [0.0, LANE_Y, 0.0],       # on the road
        [0.0, -5.0, 0.15],        # on the right sidewalk
        [0.0, LANE_Y, 1.6],       # air above the road: nearest is the road, 1.6 m below
        [-30.0, 0.0, 3.0],        # air above the centre line: road 3 m below, facades 6.5 m away
        [-16.0, -10.0, 8.0],      # inside building B2 (x -22.5..-10, |y| 7.5..14): 2.5 m from its back
        [30.0, 9.0, 5.3],         # centre of a tree crown of radius 2.3
        [0.0, -1.0, -0.3],        # inside the ground slab
    ])
    want = torch.tensor([0.0, 0.0, 1.6, 3.0, -2.5, -2.3, -0.3])
    got = field.geometry(pts)
    assert got.shape == (7,) and got.dtype == torch.float32
    assert torch.allclose(got, want, atol=1e-4), got
    # inside a parked car (body centre) and a lamp pole: negative
    assert float(field.geometry(torch.tensor([[-17.0, 2.55, 0.62], [0.0, 4.3, 3.0]])).max()) < -0.1
    # the material of the nearest part: road, building, tree
    mat = field.material(pts[[0, 4, 5]]) // 64
    assert mat.tolist() == [0, 1, 4]


def test_fast_path_equals_brute_force_min(field):
    """The pruned evaluation (objects only where their lower bound can change the min) equals the plain
    min over every primitive group evaluated everywhere."""
    g = torch.Generator().manual_seed(3)
    lo, hi = field.aabb[0], field.aabb[1]
    x = lo + torch.rand(60000, 3, generator=g) * (hi - lo)
    x[:40000, 2] = torch.rand(40000, generator=g) * 8.0 - 0.5  # most of them low, among the objects
    px, py, pz = x.T.contiguous().unbind(0)
    ref = torch.minimum(field._terrain(py.abs(), pz), field._buildings(px, py, pz, False)[0])
    for bound, sdf, _ in field._object_list:
        d_obj = sdf(px, py, pz)[0]
        assert bool((bound(px, py, pz) <= d_obj + 1e-5).all()), "a bound is not a lower bound"
        ref = torch.minimum(ref, d_obj)
    assert torch.equal(field.geometry(x), ref)


def test_gradient_norm_near_surfaces(field):
    x = _near_surface_points(field, 3000, seed=1)
    assert x.shape[0] > 1500
    h = 2e-3
    eye = torch.eye(3)
    grad = torch.stack([(field.geometry(x + h * eye[k]) - field.geometry(x - h * eye[k])) / (2 * h)
                        for k in range(3)], dim=-1)
    norm = grad.norm(dim=-1)
    assert float(((norm - 1.0).abs() < 0.05).float().mean()) > 0.95
    assert float(norm.max()) < 1.05
    # the analytic normal agrees with the difference quotient where |grad| ~ 1
    ok = (norm - 1.0).abs() < 0.01
    cos = (F.normalize(grad[ok], dim=-1) * field.normal(x[ok])).sum(-1)
    assert float(cos.quantile(0.05)) > 0.99


def test_geometry_is_differentiable(field):
    """Autograd through geometry (no in-place op breaks the graph) gives the unit outward normal."""
    k = 1.0 / math.sqrt(3.0)
    crown = [30.0 - 2.5 * k, 9.0 + 2.5 * k, 5.3 + 2.5 * k]  # 0.2 m off the crown (centre (30, 9, 5.3), r 2.3)
    x = torch.tensor([[0.0, LANE_Y, 0.3], [-16.0, -7.2, 8.0], crown], requires_grad=True)
    (grad,) = torch.autograd.grad(field.geometry(x).sum(), x)
    want = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-k, k, k]])  # road, B2 facade, tree crown
    assert torch.allclose(grad, want, atol=1e-4)
    assert torch.allclose(field.normal(x.detach()), want, atol=1e-3)


# ---------------------------------------------------------------------------------------------- background
def _dirs(el_deg: float, az_deg: float) -> torch.Tensor:
    el, az = math.radians(el_deg), math.radians(az_deg)
    return torch.tensor([[math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]])


def test_background_sky_sun_hills_ground(field):
    g = torch.Generator().manual_seed(0)
    d = F.normalize(torch.randn(20000, 3, generator=g), dim=-1)
    bg = field.background(d)
    assert bg.shape == (20000, 3) and bool(torch.isfinite(bg).all())
    assert float(bg.min()) >= 0.0 and float(bg.max()) <= 1.0
    assert float((bg - bg.mean(0)).abs().max()) > 10.0 / 255.0

    lum = lambda c: (c * torch.tensor([0.2126, 0.7152, 0.0722])).sum(-1)  # noqa: E731
    zenith, horizon = field.background(_dirs(90, 0)), field.background(_dirs(8, 180))
    assert float((zenith - horizon).abs().max()) > 0.2
    assert float(zenith[0, 2] - zenith[0, 0]) > 0.3  # deep blue overhead
    sun = field.background(field.sun_dir[None])
    assert float(lum(sun)) > float(lum(bg).max()) - 1e-6  # the sun is the brightest direction
    assert float(sun.min()) > 0.97  # a white disc...
    s = field.sun_dir
    side = F.normalize(torch.linalg.cross(s, torch.tensor([0.0, 0.0, 1.0])), dim=0)
    beside = field.background((math.cos(math.radians(2.0)) * s + math.sin(math.radians(2.0)) * side)[None])
    assert float(lum(sun) - lum(beside)) > 0.08  # ...of about a degree, in a glow
    above = lum(bg[d[:, 2] > math.sin(math.radians(10))]).mean()
    below = lum(bg[d[:, 2] < -math.sin(math.radians(5))]).mean()
    assert float(below) < float(above) - 0.15
    # hills: just above the horizon (1 degree) differs from the open sky at 8 degrees, at every azimuth
    az = torch.arange(0, 360, 15)
    low = torch.cat([field.background(_dirs(0.7, float(a))) for a in az])
    high = torch.cat([field.background(_dirs(8.0, float(a))) for a in az])
    assert float((low - high).abs().amax(-1).min()) > 0.05


def test_background_makes_the_pipeline_keep_a_skybox(field):
    constant, reason = background_is_constant(field)
    assert not constant and "unbounded" in reason
    assert field.unbounded is True


# ---------------------------------------------------------------------------------------------- radiance
def test_radiance_range_and_view_dependence(field):
    x = _near_surface_points(field, 2000, seed=2, band=0.3)
    g = torch.Generator().manual_seed(5)
    d = F.normalize(torch.randn(x.shape[0], 3, generator=g), dim=-1)
    c = field.radiance(x, d)
    assert c.shape == x.shape and bool(torch.isfinite(c).all())
    assert float(c.min()) >= 0.0 and float(c.max()) <= 1.0
    assert float(c.std(0).min()) > 0.05  # not a flat colour

    # centre of a window of building B3 (facade y = -6.5, first column at x = -7, first upper floor)
    window = torch.tensor([[-7.0, -6.5, 5.45]])
    head_on = field.radiance(window, torch.tensor([[0.0, -1.0, 0.0]]))
    grazing = field.radiance(window, F.normalize(torch.tensor([[0.9, -0.3, 0.2]]), dim=-1))
    assert float((head_on - grazing).abs().max()) > 0.05  # Fresnel reflection of the sky
    # a point on the asphalt is matte: the colour does not depend on the direction
    road = torch.tensor([[5.0, -1.0, 0.0]])
    c1 = field.radiance(road, F.normalize(torch.tensor([[1.0, 0.0, -0.2]]), dim=-1))
    c2 = field.radiance(road, F.normalize(torch.tensor([[-0.3, 0.5, -0.8]]), dim=-1))
    assert torch.allclose(c1, c2, atol=1e-5)


def test_samples_of_one_ray_see_the_same_texel(field):
    """Samples along a ray near a planar surface take their texture where the ray meets it, so the colour
    does not depend on where the marcher's steps fall (here: the end of a dash of the centre line, whose
    colour changes by 0.2 within 0.2 m of road)."""
    eye, hit = torch.tensor([0.0, LANE_Y, 1.6]), torch.tensor([3.0, 0.0, 0.0])
    d = F.normalize(hit - eye, dim=0)
    t = float((hit - eye).norm())
    x = eye + (t + torch.tensor([-0.3, -0.1, 0.0, 0.1, 0.3]))[:, None] * d
    c = field.radiance(x, d.expand(5, 3))
    assert float((c - c[2]).abs().max()) < 0.01
    on_road = field.radiance(torch.tensor([[2.88, 0.0, 0.0], [3.12, 0.0, 0.0]]), d.expand(2, 3))
    assert float((on_road[0] - on_road[1]).abs().max()) > 0.15  # the paint edge the samples straddle


# ---------------------------------------------------------------------------------------------- cameras
def test_default_cameras_drive_along_the_lane(field):
    cams = field.default_cameras(48)
    assert (cams.width, cams.height) == (320, 180) and cams.width * 9 == cams.height * 16
    fov = 2 * math.degrees(math.atan(0.5 * cams.width / float(cams.fx[0])))
    assert abs(fov - 70.0) < 0.5 and torch.allclose(cams.fx, cams.fy)
    c = cams.centers
    assert bool(((c > field.aabb[0]) & (c < field.aabb[1])).all())
    assert torch.allclose(c[:, 1], torch.full((48,), LANE_Y), atol=1e-5)
    assert torch.allclose(c[:, 2], torch.full((48,), 1.6), atol=1e-5)  # the road is at z = 0
    assert float(c[-1, 0] - c[0, 0]) > 0.7 * (AABB[1][0] - AABB[0][0])  # most of the street
    assert bool((c[1:, 0] > c[:-1, 0]).all())
    assert float(field.geometry(c).min()) > 0.5
    fwd = -cams.c2w[:, :3, 2]
    yaw = torch.rad2deg(torch.atan2(fwd[:, 1], fwd[:, 0]))
    pitch = torch.rad2deg(torch.asin(fwd[:, 2]))
    assert 1.0 < float(yaw.abs().max()) < 6.0 and float(yaw.std()) > 0.5  # a few degrees of wobble
    assert bool(((pitch > 0.0) & (pitch < 5.0)).all())
    assert torch.allclose(cams.c2w[:, :3, 0][:, 2], torch.zeros(48), atol=1e-6)  # no roll


@pytest.mark.parametrize("shift", [-3.0, -2.0, 2.0, 3.0])
def test_lane_shifted_trajectories(field, shift):
    cams = field.default_cameras(48)
    moved = field.lane_shift_cameras(48, shift)
    assert torch.equal(moved.c2w, cams.lane_shifted(shift).c2w)
    delta = (moved.centers - cams.centers).double()
    fwd = -cams.c2w[:, :3, 2].double()
    fwd_h = F.normalize(fwd * torch.tensor([1.0, 1.0, 0.0], dtype=torch.float64), dim=-1)
    assert torch.allclose(delta.norm(dim=-1), torch.full((48,), abs(shift), dtype=torch.float64), atol=1e-5)
    assert float((delta * fwd_h).sum(-1).abs().max()) < 1e-5 and float(delta[:, 2].abs().max()) < 1e-6
    right = cams.c2w[:, :3, 0].double()
    assert bool(((delta * right).sum(-1) * shift > 0).all())  # positive = to the driver's right
    assert torch.equal(moved.c2w[:, :3, :3], cams.c2w[:, :3, :3])
    assert float(field.geometry(moved.centers).min()) > 0.3


def test_lane_shifted_hand_made_camera():
    yaw, pitch = math.radians(30.0), math.radians(-20.0)
    eye = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    fwd = torch.tensor([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)],
                       dtype=torch.float64)
    pose = look_at(eye, eye + fwd, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    cam = Cameras(pose[None].float(), 100.0, 100.0, 32.0, 18.0, 64, 36)
    moved = cam.lane_shifted(2.5)
    # the right of a camera looking along azimuth 30 degrees (pitched down) is azimuth -60 degrees
    expect = eye + 2.5 * torch.tensor([math.cos(math.radians(-60)), math.sin(math.radians(-60)), 0.0],
                                      dtype=torch.float64)
    assert torch.allclose(moved.centers[0].double(), expect, atol=1e-5)
    assert torch.equal(moved.c2w[:, :3, :3], cam.c2w[:, :3, :3])
    assert (moved.width, moved.height) == (64, 36) and torch.equal(moved.fx, cam.fx)
    assert torch.equal(moved.cx, cam.cx) and torch.equal(moved.fy, cam.fy) and torch.equal(moved.cy, cam.cy)
    assert torch.allclose(cam.lane_shifted(-2.5).centers[0].double(), 2 * eye - expect, atol=1e-5)
    assert torch.equal(cam.lane_shifted(0.0).c2w, cam.c2w)

    # rolled by 40 degrees about the viewing axis: the right axis (0.573, -0.554, 0.604) rises out of the
    # horizontal plane; the move follows its horizontal part, renormalised: (0.7195, -0.6945, 0) * 2.5
    roll = math.radians(40.0)
    rz = torch.tensor([[math.cos(roll), -math.sin(roll), 0.0], [math.sin(roll), math.cos(roll), 0.0],
                       [0.0, 0.0, 1.0]], dtype=torch.float64)
    rolled = pose.clone()
    rolled[:3, :3] = pose[:3, :3] @ rz
    right = rolled[:3, 0]
    assert abs(float(right[2])) > 0.1
    horiz = torch.tensor([float(right[0]), float(right[1]), 0.0], dtype=torch.float64)
    cam2 = Cameras(rolled[None].float(), 100.0, 100.0, 32.0, 18.0, 64, 36)
    delta = cam2.lane_shifted(2.5).centers[0].double() - cam2.centers[0].double()
    assert torch.allclose(delta, 2.5 * horiz / horiz.norm(), atol=1e-5)
    by_hand = torch.tensor([2.5 * 0.7195, 2.5 * -0.6945, 0.0], dtype=torch.float64)
    assert torch.allclose(delta, by_hand, atol=1e-3)
    assert abs(float(delta.norm()) - 2.5) < 1e-5 and abs(float(delta[2])) < 1e-6

    # a camera rolled by 90 degrees has no horizontal right axis
    up = look_at(eye, eye + torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64),
                 torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    with pytest.raises(BadInputError, match="right axis"):
        Cameras(up[None].float(), 100.0, 100.0, 32.0, 18.0, 64, 36).lane_shifted(1.0)


# ---------------------------------------------------------------------------------------------- origin
def test_origin_offset_translates_everything(field):
    far = StreetField(origin=ORIGIN)
    shift = torch.tensor(ORIGIN)
    assert torch.allclose(far.aabb, field.aabb + shift, atol=1e-3)
    x = _near_surface_points(field, 2000, seed=4, band=0.3)
    x_far = (x.double() + shift.double()).float()
    assert float((far.geometry(x_far) - field.geometry(x)).abs().max()) < 5e-4
    g = torch.Generator().manual_seed(6)
    d = F.normalize(torch.randn(x.shape[0], 3, generator=g), dim=-1)
    diff = (far.radiance(x_far, d) - field.radiance(x, d)).abs()
    assert float(diff.max()) < 0.01 and float(diff.mean()) < 2e-4
    assert torch.equal(far.background(d), field.background(d))
    cams, cams_far = field.default_cameras(6), far.default_cameras(6)
    assert torch.allclose(cams_far.centers.double() - cams.centers.double(), shift.double().expand(6, 3),
                          atol=1e-3)
    assert torch.allclose(cams_far.c2w[:, :3, :3], cams.c2w[:, :3, :3], atol=1e-6)
    assert float(far.geometry(far.lane_shift_cameras(6, 3.0).centers).min()) > 0.3


# ---------------------------------------------------------------------------------------------- registry
def test_registered_as_a_synthetic_scene():
    assert SCENES["street"] is make_street and 0 < SCENE_BETA["street"] < 0.2
    sdf = make_scene("street")
    check_field(sdf)
    assert isinstance(sdf, StreetField) and sdf.kind == "sdf" and sdf.inv_s > 0
    dens = make_scene("street", kind="density")
    check_field(dens)
    assert isinstance(dens, SDFToDensityField) and dens.beta == SCENE_BETA["street"]
    assert dens.unbounded is True and callable(dens.background) and len(dens.default_cameras(3)) == 3
    sigma = dens.geometry(torch.tensor([[0.0, LANE_Y, 1.6], [0.0, LANE_Y, -0.2]]))
    assert float(sigma[0]) < 1e-6 and float(sigma[1]) > 0.9 / dens.beta


# ---------------------------------------------------------------------------------------------- render
def test_tiny_render_shows_sky_above_and_road_below(field):
    cams = field.default_cameras(4, width=64, height=36)
    out = VolumeRenderer(field, num_steps=64, occupancy=None).render(cams, 1)
    rgb, opacity = torch.from_numpy(out["rgb"]), torch.from_numpy(out["opacity"])
    assert rgb.shape == (36, 64, 3) and bool(torch.isfinite(rgb).all())
    top, bottom = rgb[:3, 24:40].reshape(-1, 3), rgb[-4:, 24:40].reshape(-1, 3)
    assert float(opacity[:3, 24:40].max()) < 0.05  # open sky over the street
    assert float((top[:, 2] - top[:, 0]).min()) > 0.15 and float(top.mean()) > 0.5  # blue and bright
    assert float(opacity[-4:].min()) > 0.95  # the road (64 steps of 1.4 m leave it a little soft)
    assert float(bottom.mean()) < 0.45 and float((bottom.amax(-1) - bottom.amin(-1)).max()) < 0.1  # grey
