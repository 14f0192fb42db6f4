"""Geometry stages on extreme inputs: marching cubes (sphere radius vs voxel, surface exactly on lattice
points, empty/full fields, a NaN region) and decimation budgets (1, above the face count)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.geometry.cleanup import decimate, is_watertight
from neuras_distill.geometry.marching import marching_cubes_field
from neuras_distill.scenes.analytic import SphereSDF

S = pytest.mark.stability


def _radius_error(mesh, centre, radius):
    r = np.linalg.norm(mesh.vertices.astype(np.float64) - np.asarray(centre, np.float64), axis=1)
    return np.abs(r - radius).max() / mesh.stats["voxel_size"]


@S(case="marching cubes sphere radius", family="geometry", reference="exact radius 0.5",
   tolerance="max vertex radius error <= 0.03 voxel (measured 0.017 / 0.009 / 0.004 at 16 / 32 / 64)")
@pytest.mark.parametrize("res", [16, 32, 64])
def test_sphere_radius(res):
    mesh = marching_cubes_field(SphereSDF(radius=0.5), res)
    assert _radius_error(mesh, (0, 0, 0), 0.5) <= 0.03
    assert is_watertight(mesh.faces)


class Plane:
    """SDF of the plane z = z0 (negative below), in the box [-1, 1]^3."""

    kind = "sdf"
    aabb = torch.tensor([[-1.0] * 3, [1.0] * 3])

    def __init__(self, z0):
        self.z0 = z0

    def geometry(self, x):
        return x[:, 2] - self.z0

    def radiance(self, x, d):
        return torch.full((x.shape[0], 3), 0.5)


@S(case="surface exactly on lattice points", family="geometry",
   reference="plane z = 0 exactly on lattice layer 8 (res 17 over [-1, 1]); the level nudge avoids zero-area faces",
   tolerance="watertight, no zero-area face, top vertices within 1e-3 of z = 0 or on the box sides")
def test_surface_on_lattice():
    mesh = marching_cubes_field(Plane(0.0), 17)
    v, f = mesh.vertices.astype(np.float64), mesh.faces
    assert f.shape[0] > 0 and is_watertight(f)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    assert area.min() > 0
    top = v[:, 2] > -1 + 1e-6
    assert np.all((np.abs(v[top, 2]) <= 1e-3) | (np.abs(np.abs(v[top]).max(axis=1) - 1) <= 0.2))


@S(case="empty SDF field", family="geometry", reference="BadInputError, exact message", tolerance="exact")
def test_empty_field():
    with pytest.raises(BadInputError, match=r"^the field has no surface inside its box: it is everywhere outside the "
                                            r"surface \(no negative SDF values\)\."):
        marching_cubes_field(Plane(-5.0), 16)


@S(case="full SDF field", family="geometry", reference="BadInputError, exact message", tolerance="exact")
def test_full_field():
    with pytest.raises(BadInputError, match=r"^the field has no surface inside its box: it is everywhere inside the "
                                            r"surface \(no positive SDF values\)\."):
        marching_cubes_field(Plane(5.0), 16)


class NaNSphere(SphereSDF):
    def geometry(self, x):
        return torch.where(x[:, 0] > 0.3, float("nan"), super().geometry(x))


@S(case="NaN region in marching cubes", family="geometry",
   reference="NaN -> outside: the sphere cut at x = 0.3, capped; radius exact away from the cut",
   tolerance="finite vertices; radius error <= 0.03 voxel for x < 0.25; grid_nonfinite counted")
def test_nan_region():
    mesh = marching_cubes_field(NaNSphere(radius=0.5), 48)
    v = mesh.vertices.astype(np.float64)
    assert np.isfinite(v).all() and mesh.stats["grid_nonfinite"] > 0
    keep = v[:, 0] < 0.25
    r = np.linalg.norm(v[keep], axis=1)
    assert np.abs(r - 0.5).max() / mesh.stats["voxel_size"] <= 0.03
    assert v[:, 0].max() <= 0.3 + mesh.stats["voxel_size"]


@S(case="decimation budget 1", family="geometry", reference="BadInputError, exact message", tolerance="exact")
def test_decimate_budget_one():
    mesh = marching_cubes_field(SphereSDF(radius=0.5), 12)
    with pytest.raises(BadInputError, match=r"^face budget must be at least 4 \(an integer number of triangles\), got 1"):
        decimate(mesh, 1)


@S(case="decimation budget above the face count", family="geometry",
   reference="the mesh unchanged (identical arrays)", tolerance="exact")
def test_decimate_budget_above():
    mesh = marching_cubes_field(SphereSDF(radius=0.5), 12)
    out = decimate(mesh, mesh.num_faces + 1000)
    assert np.array_equal(out.vertices, mesh.vertices) and np.array_equal(out.faces, mesh.faces)
    assert out.stats["decimate_budget_reached"] is True


@S(case="mesh too large for the UV unwrap", family="geometry",
   reference="BadInputError before xatlas starts (unwrap) and before any work (config), exact messages",
   tolerance="exact")
def test_unwrap_refuses_meshes_above_its_limit():
    import neuras_distill as nd
    from neuras_distill.geometry.mesh import MeshData
    from neuras_distill.geometry.unwrap import MAX_UNWRAP_FACES, unwrap

    n = MAX_UNWRAP_FACES + 1
    strip = np.arange(n + 2)
    mesh = MeshData(np.random.default_rng(0).random((n + 2, 3)), np.stack([strip[:-2], strip[1:-1], strip[2:]], 1))
    with pytest.raises(BadInputError, match=rf"^the mesh has {n} faces, more than the UV unwrap handles "
                                            rf"\({MAX_UNWRAP_FACES}\); lower --face-budget \(e.g. to 100000\)$"):
        unwrap(mesh)
    with pytest.raises(BadInputError, match=rf"^face budget {n} is more than the UV unwrap handles "
                                            rf"\({MAX_UNWRAP_FACES} faces\); pass --face-budget {MAX_UNWRAP_FACES}"):
        nd.DistillConfig().updated({"geometry": {"face_budget": n}})
