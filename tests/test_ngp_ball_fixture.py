"""The committed Instant-NGP snapshot of the ``gradient-ball`` scene (tests/data/ngp/ball.ingp, written by
``scripts/make_ngp_fixture.py --scene gradient-ball``): it loads through the adapter registry, brings the
scene's own cameras, and holds a ball where the scene has one."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from neuras_distill.registry import load_field
from neuras_distill.scenes.synthetic import make_scene

BALL = Path(__file__).parent / "data" / "ngp" / "ball.ingp"

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def field():
    return load_field(BALL)  # sniffed by content: the instant_ngp adapter


@pytest.fixture(scope="module")
def scene():
    return make_scene("gradient-ball")


def test_small_and_loaded_by_the_ngp_adapter(field):
    assert BALL.stat().st_size <= 2 * 1024 * 1024
    assert type(field).__name__ == "NgpField" and field.kind == "density"
    assert field.surface_level > 0


def test_stored_cameras_are_the_scenes_own(field, scene):
    cams = field.cameras
    want = scene.default_cameras(48, 192, 108)
    assert cams is not None and len(cams) == 48 and (cams.width, cams.height) == (192, 108)
    assert torch.allclose(cams.centers, want.centers, atol=1e-4)
    assert torch.allclose(cams.c2w[:, :3, :3], want.c2w[:, :3, :3], atol=1e-4)
    assert torch.allclose(cams.fx, want.fx, rtol=1e-5) and torch.allclose(cams.cy, want.cy, rtol=1e-5)


def test_box_holds_the_ball(field, scene):
    lo, hi = field.aabb
    assert bool((lo <= scene.center - scene.radius).all()) and bool((hi >= scene.center + scene.radius).all())
    assert bool((hi - lo < 2.0).all())  # shrunk to the occupied cells, not the whole network cube


def test_density_high_inside_and_zero_far_outside(field, scene):
    """Like any trained NeRF the ball is a shell: σ is high just under the surface, lower (but not zero)
    at the centre, and a ray through the centre is opaque; outside the fringe the density grid gates σ to 0."""
    c, r = scene.center, scene.radius
    gen = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(2000, 3, generator=gen), dim=-1)
    under = field.geometry(c + 0.45 * dirs)                  # just under the visible surface (radius 0.5)
    assert float(under.median()) > 3.0 * field.surface_level
    assert float(field.geometry(c[None])) > 0.0
    t = torch.linspace(-0.6, 0.6, 2401)                      # 8 lines through the centre, 5e-4 apart
    sigma = field.geometry((c + t[:, None, None] * dirs[None, :8]).reshape(-1, 3)).reshape(t.shape[0], 8)
    opacity = 1.0 - torch.exp(-torch.trapezoid(sigma.double(), t.double(), dim=0))
    assert float(opacity.min()) > 0.99                       # through the centre: opaque
    assert float(field.geometry(c + (r + 0.1) * dirs).max()) == 0.0   # 0.1 beyond the silhouette
    assert float(field.geometry(c + (r + 0.25) * dirs).max()) == 0.0
