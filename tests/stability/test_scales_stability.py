"""Scales: millimetre and kilometre objects and a field 1e5 from the origin, through grid sampling and marching
cubes, cleanup, decimation and UV unwrap, the teacher and the check's float32 probe."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neuras_distill.geometry.cleanup import clean_mesh, decimate
from neuras_distill.geometry.marching import marching_cubes_field
from neuras_distill.geometry.unwrap import unwrap, uv_face_areas
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF
from neuras_distill.stability.extreme import make_extreme
from neuras_distill.stability.probe import probe_field

S = pytest.mark.stability


def _err_voxels(centre, radius, res=32):
    f = SphereSDF(center=centre, radius=radius, margin=0.1 * radius, inv_s=1000.0 / radius)
    mesh = marching_cubes_field(f, res)
    r = np.linalg.norm(mesh.vertices.astype(np.float64) - np.asarray(centre, np.float64), axis=1)
    return np.abs(r - radius).max() / mesh.stats["voxel_size"]


@S(case="millimetre / metre / kilometre sphere: marching cubes", family="scale",
   reference="exact radius; the relative error is scale-free", tolerance="<= 0.03 voxel (0.009 measured at every scale)")
@pytest.mark.parametrize("radius", [1e-3, 1.0, 500.0])
def test_scale_free_mesh(radius):
    assert _err_voxels((0.0, 0.0, 0.0), radius) <= 0.03


@S(case="sphere 1e5 from the origin: marching cubes", family="scale",
   reference="exact radius 0.5; float32 ulp at 1e5 is 0.0078 = 0.23 voxel at res 32",
   tolerance="<= 0.5 voxel (measured 0.095): the float32 world positions of the Field contract bound it")
def test_far_mesh():
    assert _err_voxels((1e5, 0.0, 0.0), 0.5) <= 0.5


@S(case="mm and km sphere: teacher", family="scale",
   reference="the same image at every scale (opacity of an orbit view)", tolerance="max |Δopacity| <= 1e-3")
def test_scale_free_teacher():
    ops = []
    for radius in (1e-3, 1.0, 1e3):
        f = SphereSDF(radius=radius, margin=0.1 * radius, inv_s=1000.0 / radius)
        cams = f.default_cameras(2, 16, 16)
        ops.append(VolumeRenderer(f, num_steps=128).render(cams, 0)["opacity"])
    assert np.abs(ops[0] - ops[1]).max() <= 1e-3 and np.abs(ops[2] - ops[1]).max() <= 1e-3


@S(case="check: float32 scale probe", family="scale",
   reference="km-sphere fine; far-sphere (1e5 from origin, its field rounds positions to float32) refused with "
             "the message naming the fix", tolerance="exact prefix")
def test_scale_probe():
    assert probe_field(make_extreme("km-sphere"), samples=24, rays=32).item("scale.float32").verdict == "fine"
    item = probe_field(make_extreme("far-sphere"), samples=24, rays=32).item("scale.float32")
    assert item.verdict == "refused"
    assert item.explanation.startswith("the box lies 1e+05 units from the origin: every float32 stage works "
                                       "relative to its centre, but the field rounds positions to float32 there")
    assert item.explanation.endswith("compute positions in float64 in the field (subtract a float64 centre before "
                                     "casting)")


def _geometry_chain(centre, radius):
    """Marching cubes -> cleanup -> decimation -> UV unwrap of a sphere (the pipeline's geometry stages)."""
    f = SphereSDF(center=centre, radius=radius, margin=0.1 * radius, inv_s=1000.0 / radius)
    mesh = decimate(clean_mesh(marching_cubes_field(f, 40)), 600)
    mesh = unwrap(mesh, resolution=256)
    r = np.linalg.norm(mesh.vertices.astype(np.float64) - np.asarray(centre, np.float64), axis=1)
    uv_area = float(np.abs(uv_face_areas(mesh.uvs, mesh.faces)).sum())
    return mesh, float(np.abs(r / radius - 1.0).max()), uv_area


@S(case="mm / km sphere and a km sphere 1e5 from the origin: cleanup, decimation, UV unwrap", family="scale",
   reference="the unit sphere's chain: the same face count, the same relative radius error, the same UV area",
   tolerance="faces within 2% (600 at every scale); max |r/R - 1| <= 0.02 (0.0072-0.0081 measured; 0.87 at 1 mm "
             "before decimation worked at unit size); UV area within 15% of the unit sphere's (0.41-0.45 vs 0.45; "
             "xatlas returned an empty atlas at 1 mm before it saw the mesh at unit size)")
@pytest.mark.parametrize("centre,radius", [((0.0, 0.0, 0.0), 1e-3), ((0.0, 0.0, 0.0), 500.0),
                                           ((1e5, 0.0, 0.0), 500.0)], ids=["mm", "km", "km-at-1e5"])
def test_scale_free_cleanup_decimation_unwrap(centre, radius):
    unit, unit_err, unit_area = _geometry_chain((0.0, 0.0, 0.0), 1.0)
    mesh, err, area = _geometry_chain(centre, radius)
    assert abs(mesh.num_faces - unit.num_faces) <= 0.02 * unit.num_faces, (mesh.num_faces, unit.num_faces)
    assert err <= 0.02 and unit_err <= 0.02, (err, unit_err)
    assert abs(area - unit_area) <= 0.15 * unit_area, (area, unit_area)
    assert np.isfinite(mesh.uvs).all() and mesh.uvs.min() >= 0.0 and mesh.uvs.max() <= 1.0


class _Medium:
    """A constant density σ per unit filling a cube of side ``size`` (a thin medium kilometres across)."""

    kind = "density"

    def __init__(self, sigma: float, size: float):
        self.sigma = float(sigma)
        self.aabb = torch.tensor([[-0.5 * size] * 3, [0.5 * size] * 3])

    def geometry(self, x):
        return torch.full((x.shape[0],), self.sigma)

    def radiance(self, x, d):
        return torch.full((x.shape[0], 3), 0.5)


@S(case="thin medium kilometres across: occupancy grid", family="scale",
   reference="1 - exp(-σL), float64: σ = 1e-3 per unit over L = 2000 -> 0.8647 (the grid's absolute σ threshold "
             "of 0.01 dropped every cell: opacity 0); the same at 1 unit with σ = 2",
   tolerance="relative 1e-4 with the renderer's own occupancy grid")
@pytest.mark.parametrize("sigma,size", [(1e-3, 2000.0), (2.0, 1.0)], ids=["2km", "unit"])
def test_thin_medium_occupancy(sigma, size):
    field = _Medium(sigma, size)
    r = VolumeRenderer(field, num_steps=256)                       # occupancy "auto": built from the field
    o = torch.tensor([[-size, 0.013 * size, -0.021 * size]])
    got = float(r.render_rays(o, torch.tensor([[1.0, 0.0, 0.0]]))["opacity"][0])
    assert got == pytest.approx(-math.expm1(-sigma * size), rel=1e-4)


def _cleaned_far_sphere(offset: float, res: int = 96):
    f = SphereSDF(center=(offset,) * 3, radius=0.5, margin=0.05, inv_s=2000.0)
    mesh = marching_cubes_field(f, res)
    return mesh, clean_mesh(mesh)


@S(case="clean_mesh 1e5 from the origin: works or refuses", family="scale",
   reference="sphere r = 0.5 at (o, o, o), marching cubes at 96 (70,316-70,892 faces, watertight): where float32 "
             "positions resolve an edge the cleaned mesh stays watertight and decimates to 2000 faces with the "
             "origin's radius error (0.0014); at 1e5 (spacing 0.0078, an edge ~0.008) one BadInputError line naming "
             "the spacing and the recentring (it dropped 16,576 faces and decimated 0.0195 off before)",
   tolerance="watertight; decimated max |r - 0.5| <= 1.25x the origin's; refusal: exact prefix, one line")
@pytest.mark.parametrize("offset", [0.0, 1e3, 1e5])
def test_clean_mesh_far(offset):
    from neuras_distill.errors import BadInputError
    from neuras_distill.geometry.cleanup import is_watertight
    if offset >= 1e5:
        f = SphereSDF(center=(offset,) * 3, radius=0.5, margin=0.05, inv_s=2000.0)
        mesh = marching_cubes_field(f, 96)
        assert is_watertight(mesh.faces)
        with pytest.raises(BadInputError) as err:
            clean_mesh(mesh)
        msg = str(err.value)
        assert "\n" not in msg and msg.startswith("cannot clean a mesh 1e+05 from the origin: float32 positions "
                                                  "there are 0.0078 apart")
        assert msg.endswith("recentre it (subtract a float64 centre) first")
        return
    radius_err = []
    for o in (0.0, offset):
        mesh, cleaned = _cleaned_far_sphere(o)
        assert is_watertight(cleaned.faces)
        dec = decimate(cleaned, 2000)
        r = np.linalg.norm(dec.vertices.astype(np.float64) - o, axis=1)
        radius_err.append(float(np.abs(r - 0.5).max()))
    assert radius_err[1] <= 1.25 * radius_err[0], radius_err
