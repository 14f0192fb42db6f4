"""Tests for the ``gradient-ball`` scene (neuras_distill.scenes.gradient_ball): its soft fringe as the volume
renderer sees it, the smoothness of its colour, its cameras and its place in the scene registry."""

from __future__ import annotations

import math

import pytest
import torch

from neuras_distill.cli_parser import build_parser
from neuras_distill.errors import BadInputError
from neuras_distill.fields.base import check_field
from neuras_distill.registry import load_field
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.gradient_ball import HELD_OUT_DIP_DEG, GradientBallField
from neuras_distill.scenes.synthetic import SCENES, make_scene

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def ball() -> GradientBallField:
    return make_scene("gradient-ball")


def _opacity_at_distance(ball, distances) -> torch.Tensor:
    """Opacity of horizontal rays (along +y) passing the centre at each distance (offset along x), rendered by
    the volume renderer with steps much finer than the fringe."""
    p = torch.as_tensor(distances, dtype=torch.float32)
    o = ball.center + torch.stack([p, torch.full_like(p, -2.0), torch.zeros_like(p)], dim=-1)
    d = torch.tensor([0.0, 1.0, 0.0]).expand_as(o)
    renderer = VolumeRenderer(ball, num_steps=2048, occupancy=None)
    assert renderer.step < ball.fringe / 4
    return renderer.render_rays(o, d)["opacity"]


def test_registered_as_a_density_scene(ball):
    assert "gradient-ball" in SCENES
    check_field(ball)
    assert ball.kind == "density" and torch.equal(ball.background_color, torch.ones(3))
    assert make_scene("gradient-ball", kind="density").kind == "density"
    with pytest.raises(BadInputError, match="density"):
        make_scene("gradient-ball", kind="sdf")
    assert make_scene("sphere").kind == "sdf"  # the SDF scenes keep their own kind by default
    args = build_parser().parse_args(["from-synthetic", "gradient-ball"])
    assert args.kind is None                   # the scene's own kind, not "sdf"
    assert build_parser().parse_args(["demo"]).kind == "sdf"
    assert load_field("synthetic:gradient-ball").kind == "density"   # the synthetic adapter: its own kind


def test_box_holds_the_ball_and_its_fringe(ball):
    lo, hi = ball.aabb
    assert torch.allclose(hi - ball.center, torch.full((3,), ball.radius + 0.1))
    assert torch.allclose(ball.center - lo, torch.full((3,), ball.radius + 0.1))
    faces = ball.center + torch.tensor([[0.6, 0, 0], [0, -0.6, 0], [0, 0, 0.6], [0, 0, -0.6]])
    assert float(ball.geometry(faces).max()) < 0.01   # the renderer's occupancy threshold


def test_soft_fringe_opacity(ball):
    w, r = ball.fringe, ball.radius
    op = _opacity_at_distance(ball, [0.0, r - 2 * w, r, r + 5 * w, r + 12 * w])
    assert float(op[0]) > 0.9999                # through the centre: opaque
    assert float(op[1]) > 0.97                  # just inside the silhouette
    assert 0.35 < float(op[2]) < 0.65           # on the silhouette: half (by construction 0.5)
    assert float(op[3]) < 0.02                  # 5 fringe widths outside: ~0
    assert float(op[4]) < 1e-4
    # the rise is soft, like a trained NeRF's: from 5 % to 95 % over a few fringe widths (~4.4 w)
    p = torch.linspace(r - 6 * w, r + 6 * w, 241)
    op = _opacity_at_distance(ball, p)
    assert bool((op[1:] <= op[:-1] + 1e-4).all())  # monotone in the passing distance
    rise = float(p[op > 0.05].max() - p[op > 0.95].max())
    assert 3 * w < rise < 6 * w


def test_interior_is_opaque_within_a_short_distance(ball):
    w = ball.fringe
    assert float(ball.geometry(ball.center[None])) == pytest.approx(ball.sigma_max, rel=1e-6)
    # a ray entering head-on collects opacity 0.99 within ~2 fringe widths of the core radius
    t = torch.linspace(0.0, ball.core_radius + 0.1 - 2 * w, 4001)
    x = ball.center + torch.stack([torch.zeros_like(t), torch.zeros_like(t), ball.core_radius + 0.1 - t], -1)
    tau = torch.trapezoid(ball.geometry(x).double(), t.double())
    assert 1 - math.exp(-float(tau)) > 0.99
    # the mesh level is σ on the silhouette sphere
    on_silhouette = ball.center[None] + torch.tensor([[ball.radius, 0.0, 0.0]])
    assert ball.surface_level == pytest.approx(float(ball.geometry(on_silhouette)), rel=1e-4)


def test_colour_is_a_smooth_saturated_gradient(ball):
    gen = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(20000, 3, generator=gen), dim=-1)
    # a neighbour at 0.01 rad along a random tangent direction
    tang = torch.nn.functional.normalize(torch.linalg.cross(n, torch.randn(20000, 3, generator=gen)), dim=-1)
    n2 = n * math.cos(0.01) + tang * math.sin(0.01)
    d = -n
    x, x2 = ball.center + ball.radius * n, ball.center + ball.radius * n2
    c, c2 = ball.radiance(x, d), ball.radiance(x2, -n2)
    assert bool(((c >= 0) & (c <= 1)).all())
    assert float((c - c2).abs().max()) < 0.02          # no edges: 0.005 of a radius changes little
    sat = c.max(-1).values - c.min(-1).values
    assert float(sat.mean()) > 0.35                    # saturated
    assert float(c.std(0).min()) > 0.1                 # and it varies over the ball in every channel
    # constant along a radius (the fringe has the colour of the surface under it), poles included
    for s in (0.9, 1.05, 1.1):
        assert torch.allclose(ball.radiance(ball.center + s * ball.radius * n, d), c, atol=1e-5)
    poles = ball.center + torch.tensor([[0, 0, 0.5], [1e-4, 0, 0.5], [0, 0, -0.5], [0, 1e-4, -0.5]])
    cp = ball.radiance(poles, torch.tensor([[0.0, 0.0, -1.0]]).expand(4, 3))
    assert float((cp[0] - cp[1]).abs().max()) < 1e-3 and float((cp[2] - cp[3]).abs().max()) < 1e-3


def test_cameras_bob_below_the_helix_on_held_out_views(ball):
    cams = ball.default_cameras(48, 64, 36)
    assert len(cams) == 48 and (cams.width, cams.height) == (64, 36)
    rel = cams.centers - 0.5 * (ball.aabb[0] + ball.aabb[1])
    dist = rel.norm(dim=-1)
    assert torch.allclose(dist, dist[0].expand(48), rtol=1e-5)
    elev = torch.rad2deg(torch.asin(rel[:, 2] / dist))
    assert float(elev.min()) == pytest.approx(-5.0, abs=0.01) and float(elev.max()) < 40.01
    train, test = cams.split(12)
    held = [i for i in range(48) if i % 12 == 6]
    assert len(test) == len(held) == 4
    for i in held:  # each held-out view is lower than both training neighbours: it sees more of the bottom
        assert elev[i] < min(elev[i - 1], elev[i + 1]) - 1.0
    lowest_training = float(elev[[i for i in range(48) if i not in held]].min())
    assert float(elev[6]) < lowest_training - HELD_OUT_DIP_DEG + 0.5
    # every camera looks at the centre of the box and sees the whole ball
    fwd = -cams.c2w[:, :3, 2]
    assert torch.allclose(fwd, -rel / dist[:, None], atol=1e-5)
    half_fov_v = math.atan(cams.cy[0] / cams.fy[0])
    assert bool((torch.asin((ball.radius + 5 * ball.fringe) / dist) < 0.8 * half_fov_v).all())
    # no dip when asked
    flat = ball.default_cameras(48, 64, 36, held_out_every=0)
    rel = flat.centers - 0.5 * (ball.aabb[0] + ball.aabb[1])
    elev = torch.rad2deg(torch.asin(rel[:, 2] / rel.norm(dim=-1)))
    assert float(elev.min()) == pytest.approx(-1.0, abs=0.01)
