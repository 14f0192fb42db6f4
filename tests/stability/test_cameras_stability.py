"""Cameras at the extremes: 1 and 170 degree fields of view on 8x8 images, cameras inside the box or on its
faces, rays lying in a face, cameras inside the surface."""

from __future__ import annotations

import math

import pytest
import torch

from neuras_distill.render.cameras import Cameras
from neuras_distill.render.rays import ray_aabb
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF
from neuras_distill.stability.probe import probe_field

S = pytest.mark.stability


@S(case="field of view 1° and 170° on 8x8 images", family="cameras",
   reference="angle between the outer pixel-centre rays of row 4: directions (±3.5, -0.5, -f) / |.|, "
             "f = 4 / tan(fov / 2), float64",
   tolerance="1e-4 rad; unit, finite directions")
@pytest.mark.parametrize("fov", [1.0, 170.0])
def test_fov_extremes(fov):
    cams = Cameras.orbit((0, 0, 0), 3.0, 2, width=8, height=8, fov_deg=fov)
    o, d = cams.rays(0)
    assert torch.isfinite(d).all() and torch.allclose(d.norm(dim=-1), torch.ones(8, 8), atol=1e-6)
    f = 4.0 / math.tan(math.radians(fov) / 2)
    a2, b2 = 3.5 ** 2, 0.5 ** 2
    expected = math.acos((-a2 + b2 + f * f) / (a2 + b2 + f * f))
    got = math.acos(float((d[4, 0] * d[4, 7]).sum().clamp(-1, 1)))
    assert got == pytest.approx(expected, abs=1e-4)


@S(case="1° camera renders the sphere", family="cameras",
   reference="a 1° view aimed at the centre of a sphere it is outside of: every pixel opaque", tolerance="opacity >= 0.999")
def test_narrow_fov_render():
    field = SphereSDF(radius=0.5)
    cams = Cameras.orbit((0, 0, 0), 3.0, 2, width=8, height=8, fov_deg=1.0)
    out = VolumeRenderer(field, num_steps=128).render(cams, 0)
    assert out["opacity"].min() >= 0.999


BOX = torch.tensor([[-1.0] * 3, [1.0] * 3])


@S(case="camera inside the box", family="cameras", reference="t_near = 0, t_far = distance to the face",
   tolerance="exact (float32)")
def test_camera_inside_box():
    t0, t1, hit = ray_aabb(torch.tensor([[0.25, 0.0, 0.0]]), torch.tensor([[1.0, 0.0, 0.0]]), BOX)
    assert bool(hit[0]) and float(t0[0]) == 0.0 and float(t1[0]) == 0.75


@S(case="ray lying in a face of the box", family="cameras",
   reference="origin on the face y = 1, direction along x: hit on [2, 4] (naive slab: NaN)", tolerance="exact")
def test_ray_in_face():
    t0, t1, hit = ray_aabb(torch.tensor([[-3.0, 1.0, 0.0]]), torch.tensor([[1.0, 0.0, 0.0]]), BOX)
    assert bool(hit[0]) and float(t0[0]) == 2.0 and float(t1[0]) == 4.0


@S(case="ray grazing an edge and parallel outside", family="cameras",
   reference="along the edge y = z = 1: hit [2, 4]; parallel at y = 1 + 1e-6: miss", tolerance="exact")
def test_grazing_edge():
    o = torch.tensor([[-3.0, 1.0, 1.0], [-3.0, 1.0 + 1e-6, 0.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    t0, t1, hit = ray_aabb(o, d, BOX)
    assert hit.tolist() == [True, False]
    assert (float(t0[0]), float(t1[0])) == (2.0, 4.0)


@S(case="cameras inside the surface", family="cameras",
   reference="check: cameras.inside adapted, naming the cameras whose centre has SDF < 0; all inside: refused",
   tolerance="exact ids and message prefix")
def test_cameras_inside_surface():
    field = SphereSDF(radius=0.5)
    outside = Cameras.orbit((0, 0, 0), 3.0, 3, width=8, height=8)
    c2w = outside.c2w.clone()
    c2w[1, :3, 3] = torch.tensor([0.1, 0.0, 0.0])     # camera 1 inside the sphere
    cams = Cameras(c2w, outside.fx, outside.fy, outside.cx, outside.cy, 8, 8)
    item = probe_field(field, cams, samples=24, rays=32).item("cameras.inside")
    assert item.verdict == "adapted" and item.values["inside_ids"] == [1]
    assert item.explanation.startswith("1 of 3 camera centres are inside (SDF < 0)")
    c2w[:, :3, 3] = torch.tensor([0.1, 0.0, 0.0])
    cams = Cameras(c2w, outside.fx, outside.fy, outside.cx, outside.cy, 8, 8)
    item = probe_field(field, cams, samples=24, rays=32).item("cameras.inside")
    assert item.verdict == "refused" and item.explanation.startswith("every camera centre is inside the geometry")


@S(case="camera inside the surface: teacher", family="cameras",
   reference="NeuS log-space α from inside: the ray exits at r = 0.5 and sees nothing else (opacity of the exit shell "
             "only), never opaque at the first sample", tolerance="opacity <= 0.01 (exit side: SDF increasing, α = 0)")
def test_teacher_from_inside():
    field = SphereSDF(radius=0.5, inv_s=1e3)
    out = VolumeRenderer(field, num_steps=256, occupancy=None).render_rays(torch.zeros(1, 3) + 0.05,
                                                                           torch.tensor([[1.0, 0.0, 0.0]]))
    assert float(out["opacity"][0]) <= 0.01


class _UnitSlab:
    """Density 1 for |x| <= 0.5 in the box [-1, 1]^3 (zero elsewhere)."""

    kind = "density"
    aabb = torch.tensor([[-1.0] * 3, [1.0] * 3])

    def geometry(self, x):
        return torch.where(x[:, 0].abs() <= 0.5, 1.0, 0.0)

    def radiance(self, x, d):
        return torch.full((x.shape[0], 3), 0.5)


@S(case="ray lying in a max face of the box: occupancy grid", family="cameras",
   reference="origin (-3, 0, 1) on the face z = 1 (the box's max), direction +x, through a unit-density slab 1 thick: "
             "opacity 1 - e^-1 = 0.6321, as without the grid (the grid mapped points on a max face out of the grid: "
             "opacity 0); the same on the faces y = 1, y = -1 and z = -1",
   tolerance="absolute 1e-4; with and without the occupancy grid")
@pytest.mark.parametrize("origin", [(-3.0, 0.0, 1.0), (-3.0, 1.0, 0.0), (-3.0, -1.0, 0.0), (-3.0, 0.0, -1.0)],
                         ids=["z-max", "y-max", "y-min", "z-min"])
def test_ray_in_max_face_occupancy(origin):
    field = _UnitSlab()
    o, d = torch.tensor([origin]), torch.tensor([[1.0, 0.0, 0.0]])
    for occupancy in ("auto", None):
        got = float(VolumeRenderer(field, num_steps=256, occupancy=occupancy).render_rays(o, d)["opacity"][0])
        assert got == pytest.approx(-math.expm1(-1.0), abs=1e-4), occupancy
