"""Tests for neuras_distill.geometry: grid sampling, marching cubes, cleanup/decimation, culling, unwrap.

The fields here are tiny analytic ones defined in this file (no dependency on neuras_distill.fields).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.geometry.cleanup import clean_mesh, decimate, is_watertight
from neuras_distill.config import GeometryConfig
from neuras_distill.geometry.extract import extract_surface, unwrap_surface
from neuras_distill.geometry.grid import grid_spec, sample_grid
from neuras_distill.geometry.lattice_mc import signed_volume
from neuras_distill.geometry.marching import marching_cubes_field
from neuras_distill.geometry.mesh import MeshData
from neuras_distill.geometry.unwrap import CRASH_HOOK_ENV, unwrap, uv_face_areas
from neuras_distill.geometry.visibility import cull_unseen_faces
from neuras_distill.render.cameras import Cameras, look_at


# ---------------------------------------------------------------------------------------------- analytic fields
class SphereSDF:
    kind = "sdf"

    def __init__(self, radius=0.5, center=(0.0, 0.0, 0.0), aabb=((-1, -1, -1), (1, 1, 1))):
        self.radius = radius
        self.center = torch.tensor(center, dtype=torch.float32)
        self.aabb = torch.tensor(aabb, dtype=torch.float32)

    def geometry(self, x):
        return (x - self.center).norm(dim=-1) - self.radius

    def exact(self, p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p.astype(np.float64) - self.center.double().numpy(), axis=-1) - self.radius


class TorusSDF:
    kind = "sdf"

    def __init__(self, major=0.6, minor=0.25):
        self.major, self.minor = major, minor
        self.aabb = torch.tensor([[-1.0, -1.0, -0.5], [1.0, 1.0, 0.5]])  # non-cubic box

    def geometry(self, x):
        q = torch.stack([x[:, :2].norm(dim=-1) - self.major, x[:, 2]], dim=-1)
        return q.norm(dim=-1) - self.minor

    def exact(self, p: np.ndarray) -> np.ndarray:
        p = p.astype(np.float64)
        q = np.stack([np.linalg.norm(p[:, :2], axis=-1) - self.major, p[:, 2]], axis=-1)
        return np.linalg.norm(q, axis=-1) - self.minor

    def gradient(self, p: np.ndarray) -> np.ndarray:
        p = p.astype(np.float64)
        rho = np.linalg.norm(p[:, :2], axis=-1, keepdims=True)
        ring = np.concatenate([p[:, :2] / rho * self.major, np.zeros_like(rho)], axis=-1)
        d = p - ring
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


class LaplaceDensity:
    """VolSDF density sigma = Psi_beta(-sdf) / beta of an SDF (peak 1/beta inside, 1/(2 beta) on the surface)."""

    kind = "density"

    def __init__(self, sdf, beta):
        self.sdf, self.beta = sdf, beta
        self.aabb = sdf.aabb

    def geometry(self, x):
        s = self.sdf.geometry(x)
        psi = torch.where(s >= 0, 0.5 * torch.exp(-s / self.beta), 1.0 - 0.5 * torch.exp(s / self.beta))
        return psi / self.beta


class NoSurface:
    def __init__(self, kind, value):
        self.kind, self.value = kind, value
        self.aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])

    def geometry(self, x):
        return torch.full((x.shape[0],), self.value)


# ---------------------------------------------------------------------------------------------- helpers
def surface_samples(mesh: MeshData, per_face: int = 4, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    bary = rng.dirichlet([1.0, 1.0, 1.0], size=(mesh.num_faces, per_face))
    tri = mesh.vertices[mesh.faces].astype(np.float64)
    return np.einsum("fsk,fkd->fsd", bary, tri).reshape(-1, 3)


def face_normals(mesh: MeshData) -> np.ndarray:
    tri = mesh.vertices[mesh.faces].astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def voxel_errors(mesh, exact, voxel):
    """(mean vertex distance, mean face-point distance, max face-point distance) to the true surface, in voxels."""
    dv = np.abs(exact(mesh.vertices)) / voxel
    df = np.abs(exact(surface_samples(mesh))) / voxel
    return float(dv.mean()), float(df.mean()), float(df.max())


@pytest.fixture(scope="module")
def sphere_mesh():
    return marching_cubes_field(SphereSDF(), 64)


# ---------------------------------------------------------------------------------------------- grid
def test_chunked_grid_equals_one_shot_and_replaces_nonfinite():
    def fn(x):
        v = x.norm(dim=-1) - 0.5 + 0.1 * torch.sin(7 * x[:, 0]) * x[:, 1]
        v[x[:, 0] > 0.9] = float("nan")
        return v

    aabb = torch.tensor([[-1.0, -0.7, -0.3], [1.0, 0.7, 0.3]])
    one_stats, chunk_stats = {}, {}
    one = sample_grid(fn, aabb, 40, outside=7.0, chunk_points=10 ** 9, stats=one_stats)
    chunked = sample_grid(fn, aabb, 40, outside=7.0, chunk_points=333, stats=chunk_stats)  # rows inside a slice
    slabs = sample_grid(fn, aabb, 40, outside=7.0, chunk_points=40 * 40 * 3)
    assert one.dtype == np.float32 and one.shape == tuple(grid_spec(aabb, 40).shape)
    assert np.array_equal(one, chunked) and np.array_equal(one, slabs)
    assert one_stats["grid_nonfinite"] == chunk_stats["grid_nonfinite"] > 0
    assert np.isfinite(one).all() and (one == 7.0).sum() >= one_stats["grid_nonfinite"]
    # values sit exactly at origin + index * spacing
    spec = grid_spec(aabb, 40)
    i, j, k = 5, 11, 3
    p = torch.tensor(spec.origin + np.array([i, j, k]) * spec.spacing, dtype=torch.float32)[None]
    assert one[i, j, k] == np.float32(fn(p)[0])


def test_noncubic_box_gives_cubic_voxels_covering_the_box():
    aabb = torch.tensor([[0.0, 0.0, 0.0], [2.0, 1.0, 0.55]])
    spec = grid_spec(aabb, 41)
    assert np.allclose(spec.spacing, 0.05) and spec.shape == (41, 21, 12)
    box = spec.box
    assert (box[0] <= aabb.numpy()[0] + 1e-6).all() and (box[1] >= aabb.numpy()[1] - 1e-6).all()
    assert ((box[1] - box[0]) - (aabb[1] - aabb[0]).numpy()).max() < 0.05  # grown by less than a voxel
    explicit = grid_spec(aabb, (5, 6, 7))  # per-axis resolution used as given
    assert explicit.shape == (5, 6, 7) and np.allclose(explicit.box, aabb.numpy())


# ---------------------------------------------------------------------------------------------- marching cubes
def test_sphere_sdf_mesh_accuracy_and_orientation(sphere_mesh):
    field = SphereSDF()
    mesh = sphere_mesh
    voxel = mesh.stats["voxel_size"]
    mean_v, mean_f, max_f = voxel_errors(mesh, field.exact, voxel)
    print(f"sphere sdf 64^3: vertex {mean_v:.4f} vox, face points {mean_f:.4f} vox (max {max_f:.3f})")
    assert mean_v < 0.05 and mean_f < 0.1 and max_f < 0.5
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normals(mesh), centroids) > 0).all()  # every face points outwards
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(4 / 3 * math.pi * 0.5 ** 3, rel=0.01)
    assert is_watertight(mesh.faces)


def test_torus_in_noncubic_box():
    field = TorusSDF()
    mesh = marching_cubes_field(field, 80)
    voxel = mesh.stats["voxel_size"]
    assert mesh.stats["grid_shape"] == [80, 80, 41]
    mean_v, mean_f, max_f = voxel_errors(mesh, field.exact, voxel)
    print(f"torus sdf 80: vertex {mean_v:.4f} vox, face points {mean_f:.4f} vox (max {max_f:.3f})")
    assert mean_v < 0.05 and mean_f < 0.1 and max_f < 0.5
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normals(mesh), field.gradient(centroids)) > 0).all()
    exact_volume = 2 * math.pi ** 2 * field.major * field.minor ** 2
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(exact_volume, rel=0.01)


def test_surface_cut_by_box_is_closed():
    field = SphereSDF(radius=0.5, center=(0.8, 0.0, 0.0))  # pokes out of the +x face of the box
    mesh = marching_cubes_field(field, 48)
    assert is_watertight(mesh.faces) and signed_volume(mesh.vertices, mesh.faces) > 0
    assert mesh.vertices[:, 0].max() <= 1.0 + 1e-4  # the cap lies on the box face


@pytest.mark.parametrize("beta_voxels", [0.2, 0.5, 2.0])
def test_density_field_surface_at_sdf_zero(beta_voxels):
    """Level rule min(ln2/voxel, peak/2): sharp densities put the surface < 0.27 voxel outside sdf = 0,
    soft ones (beta >= 0.72 voxel) exactly at sdf = 0 (half the Laplace peak)."""
    sdf = SphereSDF()
    res = 64
    voxel = 2.0 / (res - 1)
    field = LaplaceDensity(sdf, beta_voxels * voxel)
    mesh = marching_cubes_field(field, res)
    signed = sdf.exact(surface_samples(mesh)) / voxel
    print(f"density beta={beta_voxels} vox: level {mesh.stats['mc_level']:.3f}, "
          f"mean sdf {signed.mean():+.4f} vox, mean |sdf| {np.abs(signed).mean():.4f} vox")
    assert abs(signed.mean()) < 0.3 and np.abs(signed).max() < 0.7
    if beta_voxels >= 1.0:
        assert abs(signed.mean()) < 0.1
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    assert (np.einsum("ij,ij->i", face_normals(mesh), centroids) > 0).all()
    assert signed_volume(mesh.vertices, mesh.faces) > 0


def test_explicit_density_level_and_exact_level_ties():
    sdf = SphereSDF()
    field = LaplaceDensity(sdf, 0.01)
    mesh = marching_cubes_field(field, 48, level=50.0)  # 1/(2 beta) = 50: the zero level set
    voxel = mesh.stats["voxel_size"]
    assert abs(sdf.exact(surface_samples(mesh)).mean()) / voxel < 0.2  # beta = 0.24 voxel: very sharp
    # a quantised field where many grid values equal the level: nudged, no zero-area faces, still closed
    q = SphereSDF()
    q.geometry = lambda x: torch.round((x.norm(dim=-1) - 0.5) * 20) / 20
    mq = marching_cubes_field(q, 40)
    tri = mq.vertices[mq.faces].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    assert (area > 0).all() and is_watertight(mq.faces)


@pytest.mark.parametrize("field", [NoSurface("sdf", 1.0), NoSurface("sdf", -1.0), NoSurface("density", 0.0),
                                   SphereSDF(radius=0.3, center=(5.0, 0.0, 0.0))])
def test_no_surface_raises(field):
    with pytest.raises(BadInputError, match="no surface inside its box"):
        marching_cubes_field(field, 16)


# ---------------------------------------------------------------------------------------------- cleanup / decimation
def test_clean_removes_junk(sphere_mesh):
    v, f = sphere_mesh.vertices, sphere_mesh.faces
    speck = np.array([[0.9, 0.9, 0.9], [0.91, 0.9, 0.9], [0.9, 0.91, 0.9]], dtype=np.float32)
    nan_v = np.array([[np.nan, 0, 0]], dtype=np.float32)
    v2 = np.concatenate([v, speck, nan_v, np.zeros((5, 3), np.float32)])
    n = len(v)
    f2 = np.concatenate([f, f[:10], [[n, n + 1, n + 2], [0, 0, 1], [n + 3, 0, 1]]])
    cleaned = clean_mesh(MeshData(v2, f2))
    assert cleaned.num_faces == sphere_mesh.num_faces and cleaned.num_vertices == sphere_mesh.num_vertices
    assert cleaned.stats["clean_components_removed"] == 1 and np.isfinite(cleaned.vertices).all()
    assert is_watertight(cleaned.faces)


def test_clean_keeps_a_small_component_the_views_see_as_surface(sphere_mesh):
    """A small piece is a floater unless the training views see the field's surface on it (a dark floor tile a
    partly trained field set apart from its neighbours): with two seen points on it, it stays."""
    v, f = sphere_mesh.vertices, sphere_mesh.faces
    tile = np.array([[2.0, 0.0, 0.0], [2.1, 0.0, 0.0], [2.0, 0.1, 0.0], [2.1, 0.1, 0.0]], dtype=np.float32)
    n = len(v)
    mesh = MeshData(np.concatenate([v, tile]), np.concatenate([f, [[n, n + 1, n + 2], [n + 1, n + 3, n + 2]]]))
    assert clean_mesh(mesh).num_faces == sphere_mesh.num_faces            # a floater without evidence
    seen = np.array([[2.04, 0.03, 0.0], [2.07, 0.06, 0.001]])
    kept = clean_mesh(mesh, keep_near=seen, keep_radius=0.1)
    assert kept.num_faces == sphere_mesh.num_faces + 2 and kept.stats["clean_components_kept_seen"] == 1
    one = clean_mesh(mesh, keep_near=seen[:1], keep_radius=0.1)           # one point is not enough
    assert one.num_faces == sphere_mesh.num_faces and one.stats["clean_components_removed"] == 1


def test_face_components_join_faces_that_share_a_vertex():
    from neuras_distill.geometry.cleanup import face_components

    faces = np.array([[0, 1, 2], [2, 3, 4], [5, 6, 7], [7, 8, 9], [10, 11, 12], [4, 13, 14]])
    labels = face_components(faces, 16)                    # vertex 15 belongs to no face
    assert labels.shape == (6,) and labels.dtype == np.int64
    assert labels[0] == labels[1] == labels[5] and labels[2] == labels[3]
    assert len({labels[0], labels[2], labels[4]}) == 3
    assert face_components(np.zeros((0, 3), np.int64), 4).shape == (0,)


def test_decimate_reaches_budget_and_stays_close(sphere_mesh):
    field = SphereSDF()
    voxel = sphere_mesh.stats["voxel_size"]
    out = decimate(clean_mesh(sphere_mesh), 2000)
    assert 1800 <= out.num_faces <= 2000 and out.stats["decimate_budget_reached"]
    mean_v, mean_f, max_f = voxel_errors(out, field.exact, voxel)
    print(f"decimated {sphere_mesh.num_faces}->{out.num_faces}: vertex {mean_v:.3f} vox, face {mean_f:.3f} vox")
    assert mean_v < 0.25 and mean_f < 0.5
    assert is_watertight(out.faces) and signed_volume(out.vertices, out.faces) > 0


class CarOnRoadSDF:
    """A 400 m road strip (z = 0) with a 4 x 2 x 1.5 m box on it at x = 0: a small feature on a large plane,
    as the city's cars (the mesh is collapsed in a frame where the car is 1/100 of the extent)."""
    kind = "sdf"
    aabb = torch.tensor([[-200.0, -10.0, -2.0], [200.0, 10.0, 4.0]])

    def geometry(self, x):
        q = (x - torch.tensor([0.0, 0.0, 0.75])).abs() - torch.tensor([2.0, 1.0, 0.75])
        box = q.clamp(min=0).norm(dim=-1) + q.max(dim=-1).values.clamp(max=0)
        return torch.minimum(x[:, 2], box)


@pytest.mark.slow
def test_decimate_keeps_small_features_on_large_meshes():
    """The planar quadric's weight shrinks for fine meshes (cleanup.planar_weight): at pymeshlab's fixed 1e-3
    the car is flattened into the road on a mesh 1/1000 of a voxel fine, with the scaled weight it stands."""
    import neuras_distill.geometry.cleanup as cleanup

    mesh = clean_mesh(marching_cubes_field(CarOnRoadSDF(), 800))
    weight = cleanup.planar_weight(mesh.vertices.astype(np.float64), mesh.faces)
    assert weight < 0.3 * cleanup.PLANAR_WEIGHT
    assert cleanup.planar_weight(*sphere_like_ordinary_mesh()) == cleanup.PLANAR_WEIGHT

    def car_height(m):
        v = m.vertices
        near = (np.abs(v[:, 0]) < 2.5) & (np.abs(v[:, 1]) < 1.5)
        return float(v[near, 2].max()) if near.any() else 0.0

    out = decimate(mesh, 3000)
    assert out.stats["decimate_planar_weight"] == pytest.approx(weight)
    assert car_height(out) > 1.3, car_height(out)
    original = cleanup.planar_weight
    try:   # the fixed weight: the same decimation loses the car (proves the test can fail)
        cleanup.planar_weight = lambda v, f: cleanup.PLANAR_WEIGHT
        flat = decimate(mesh, 3000)
    finally:
        cleanup.planar_weight = original
    assert car_height(flat) < car_height(out) - 0.3, (car_height(flat), car_height(out))


def sphere_like_ordinary_mesh():
    m = clean_mesh(marching_cubes_field(SphereSDF(), 64))
    return m.vertices.astype(np.float64), m.faces


@pytest.mark.parametrize("budget", [0, 3, -5, 100.0, True, "1000"])
def test_bad_face_budget(sphere_mesh, budget):
    with pytest.raises(BadInputError, match="face budget must be at least"):
        decimate(sphere_mesh, budget)


# ---------------------------------------------------------------------------------------------- visibility
def test_cull_keeps_front_removes_back():
    mesh = decimate(marching_cubes_field(SphereSDF(), 48), 4000)
    poses = torch.stack([look_at(torch.tensor([5.0 * math.cos(a), 5.0 * math.sin(a), 0.3]), torch.zeros(3),
                                 torch.tensor([0.0, 0.0, 1.0])) for a in (-0.1, 0.0, 0.1)]).float()
    f = 0.5 * 200 / math.tan(math.radians(10))
    cams = Cameras(poses, f, f, 100.0, 75.0, 200, 150)
    out = cull_unseen_faces(mesh, cams, margin_deg=0)
    frac = out.stats["culled_faces"] / mesh.num_faces
    print(f"culled {out.stats['culled_faces']} of {mesh.num_faces} ({frac:.1%})")
    assert 0.4 < frac < 0.6
    # every face clearly facing some camera is kept (compare face centroids)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    normals = face_normals(mesh)
    facing = np.zeros(mesh.num_faces, dtype=bool)
    for c in cams.centers.numpy():
        to_cam = c - centroids
        facing |= np.einsum("ij,ij->i", normals, to_cam / np.linalg.norm(to_cam, axis=-1, keepdims=True)) > 0.05
    kept = {tuple(np.round(c, 5)) for c in out.vertices[out.faces].mean(axis=1)}
    assert all(tuple(np.round(c, 5)) in kept for c in centroids[facing])
    assert out.faces.max() < out.num_vertices == len(np.unique(out.faces))  # no unreferenced vertices
    away = Cameras(look_at(torch.tensor([5.0, 0, 0]), torch.tensor([10.0, 0, 0]), torch.tensor([0, 0, 1.0])).float(),
                   f, f, 100.0, 75.0, 200, 150)
    with pytest.raises(BadInputError, match="no training camera sees"):
        cull_unseen_faces(mesh, away)


def test_cull_margin_keeps_what_nearby_cameras_see():
    """Cameras on the equator of a sphere: with the default margin, a held-out camera 14 degrees below them
    sees no culled face; without a margin it looks into the culled bottom."""
    from neuras_distill.geometry.visibility import seen_faces

    mesh = decimate(marching_cubes_field(SphereSDF(), 48), 4000)
    up = torch.tensor([0.0, 0.0, 1.0])
    ring = [torch.tensor([5.0 * math.cos(a), 5.0 * math.sin(a), 0.0]) for a in np.linspace(0, 2 * math.pi, 12,
                                                                                            endpoint=False)]
    f = 0.5 * 200 / math.tan(math.radians(15))
    train = Cameras(torch.stack([look_at(e, torch.zeros(3), up) for e in ring]).float(), f, f, 100.0, 75.0, 200, 150)
    low = math.radians(-14)
    eye = torch.tensor([5.0 * math.cos(low), 0.0, 5.0 * math.sin(low)])
    held_out = Cameras(look_at(eye, torch.zeros(3), up).float()[None], f, f, 100.0, 75.0, 200, 150)
    tight = cull_unseen_faces(mesh, train, margin_deg=0)
    kept = cull_unseen_faces(mesh, train)
    assert kept.stats["cull_margin_deg"] == 15.0 and kept.stats["cull_seen_nearby"] > 0
    assert kept.stats["culled_faces"] < tight.stats["culled_faces"]

    def missed_by(out):              # held-out faces (of the full mesh) whose centroid is not in ``out``
        seen = seen_faces(mesh, held_out)[0]
        kept_c = {tuple(np.round(c, 5)) for c in out.vertices[out.faces].mean(axis=1)}
        cents = mesh.vertices[mesh.faces[seen]].mean(axis=1)
        return sum(tuple(np.round(c, 5)) not in kept_c for c in cents)

    assert missed_by(tight) > 3
    assert missed_by(kept) == 0


def test_raycast_first_hit_miss_and_signed_distance():
    """geometry.raycast (the libigl wrapper): face ids with -1 / inf for a miss, signed distance of a cube."""
    from neuras_distill.geometry.raycast import cast_rays, raycasting_scene, signed_distance

    # the unit cube [0, 1]^3 as 12 triangles (faces 0, 1 on z = 0, faces 2, 3 on z = 1)
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], np.float64)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                  [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int64)
    scene = raycasting_scene(v, f)
    rays = np.array([[0.25, 0.75, 3.0, 0, 0, -2.0],      # straight down onto the top (z = 1) at t = 1
                     [0.25, 0.75, -3.0, 0, 0, 1.0],      # straight up onto the bottom at t = 3
                     [3.0, 3.0, 3.0, 0, 0, 1.0]], np.float32)   # away: a miss
    ids, t_hit = cast_rays(scene, rays)
    assert ids.dtype == np.int64 and ids.shape == t_hit.shape == (3,)
    assert ids[0] in (2, 3) and ids[1] in (0, 1) and ids[2] == -1
    np.testing.assert_allclose(t_hit[:2], [1.0, 3.0], atol=1e-6)
    assert np.isinf(t_hit[2])
    pts = np.array([[[0.5, 0.5, 0.5], [0.5, 0.5, 1.25]], [[0.1, 0.5, 0.5], [2.0, 0.5, 0.5]]])
    d = signed_distance(scene, pts)
    assert d.shape == (2, 2) and d.dtype == np.float32
    np.testing.assert_allclose(d, [[-0.5, 0.25], [-0.1, 1.0]], atol=1e-6)


# ---------------------------------------------------------------------------------------------- unwrap
def uv_overlap_fraction(uvs, faces, n=256):
    """Fraction of covered sample points (n x n texel centres) covered by more than one uv triangle."""
    count = np.zeros((n, n), dtype=np.int32)
    tri = uvs[faces].astype(np.float64) * n - 0.5  # in texel-centre index units
    for t in tri:
        lo = np.clip(np.ceil(t.min(axis=0)).astype(int), 0, n - 1)
        hi = np.clip(np.floor(t.max(axis=0)).astype(int), 0, n - 1)
        if (hi < lo).any():
            continue
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="xy")
        p = np.stack([xs.ravel(), ys.ravel()], axis=-1).astype(np.float64)
        a, b, c = t
        d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        w1 = ((p[:, 0] - a[0]) * (c[1] - a[1]) - (p[:, 1] - a[1]) * (c[0] - a[0])) / d
        w2 = ((b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])) / d
        inside = (w1 >= 0) & (w2 >= 0) & (w1 + w2 <= 1)
        count[ys.ravel()[inside], xs.ravel()[inside]] += 1
    covered = count > 0
    return float((count > 1).sum() / max(1, covered.sum())), float(covered.mean())


def test_unwrap_uvs_valid(sphere_mesh):
    mesh = decimate(sphere_mesh, 1500)
    out = unwrap(mesh, resolution=256)
    assert out.uvs is not None and out.uvs.dtype == np.float32 and np.isfinite(out.uvs).all()
    assert out.uvs.min() >= 0.0 and out.uvs.max() <= 1.0
    assert out.num_faces == mesh.num_faces and out.num_vertices >= mesh.num_vertices
    assert np.array_equal(out.vertices[out.faces], mesh.vertices[mesh.faces])  # same faces, same order
    areas = uv_face_areas(out.uvs, out.faces)
    assert (np.abs(areas) > 1e-9).all() and np.abs(areas).sum() <= 1.0
    overlap, covered = uv_overlap_fraction(out.uvs, out.faces)
    print(f"unwrap: {out.stats['uv_charts']} charts, atlas {out.stats['uv_atlas_width']}x"
          f"{out.stats['uv_atlas_height']}, utilization {out.stats['uv_utilization']:.2f}, overlap {overlap:.4f}")
    assert overlap < 0.01 and covered > 0.3
    assert out.stats["uv_padding_texels"] >= 2.0 and out.stats["uv_attempts"] == ["ok"]


def test_unwrap_at_another_side_packs_the_trial_charts_again(sphere_mesh):
    """The final unwrap at a side other than the trial's reuses the trial's charts (only packing runs again):
    same faces, same chart count, valid non-overlapping uvs laid out for the new side."""
    from neuras_distill.geometry.extract import Surface, trial_vertex_sources, unwrap_surface

    mesh = decimate(sphere_mesh, 1500)
    trial = unwrap(mesh, resolution=1024)
    source = trial_vertex_sources(mesh, trial)
    assert np.array_equal(mesh.vertices[source], trial.vertices)
    out = unwrap_surface(Surface(mesh, None, trial, 1024), 128)
    assert out.stats["uv_charts_from_trial"] is True and out.stats["uv_resolution"] == 128
    assert out.stats["uv_charts"] == trial.stats["uv_charts"]
    assert np.array_equal(out.vertices[out.faces], mesh.vertices[mesh.faces])
    assert out.uvs.min() >= 0.0 and out.uvs.max() <= 1.0
    overlap, covered = uv_overlap_fraction(out.uvs, out.faces)
    assert overlap < 0.01 and covered > 0.3
    assert out.stats["uv_padding_texels"] >= 2.0
    # the same texel density the charts would get unwrapped afresh at 128 (within 15% of uv area)
    fresh = unwrap(mesh, resolution=128)
    assert abs(out.uv_area() / fresh.uv_area() - 1.0) < 0.15


def test_a_rough_layer_is_laid_out_from_smoothed_positions(sphere_mesh):
    """``extract.chart_layout``: a crumpled surface (a trained NeRF's level set after decimation) gets far fewer
    UV charts when xatlas lays them out from smoothed positions; a smooth layer keeps its own vertices."""
    from neuras_distill.geometry.extract import chart_layout

    mesh = decimate(sphere_mesh, 2000)
    assert chart_layout(mesh) is mesh.vertices and "layout_smoothing_steps" not in mesh.stats
    rng = np.random.default_rng(0)
    normals = mesh.vertices / np.linalg.norm(mesh.vertices, axis=1, keepdims=True)
    edge = float(np.linalg.norm(mesh.vertices[mesh.faces[:, 0]] - mesh.vertices[mesh.faces[:, 1]], axis=1).mean())
    crumpled = MeshData(mesh.vertices + (0.6 * edge * rng.standard_normal((mesh.num_vertices, 1)) * normals)
                        .astype(np.float32), mesh.faces, None, {"smoothing_steps": 30})
    layout = chart_layout(crumpled)
    assert layout.shape == crumpled.vertices.shape and crumpled.stats["layout_smoothing_steps"] > 0
    raw = unwrap(crumpled, resolution=256)
    smooth = unwrap(crumpled, resolution=256, layout_vertices=layout)
    print(f"charts: crumpled {raw.stats['uv_charts']}, laid out smoothed {smooth.stats['uv_charts']}")
    assert smooth.stats["uv_charts"] < 0.5 * raw.stats["uv_charts"]
    assert np.array_equal(smooth.vertices[smooth.faces], crumpled.vertices[crumpled.faces])  # geometry not moved


def test_unwrap_refuses_empty_and_huge(sphere_mesh):
    with pytest.raises(BadInputError, match="empty"):
        unwrap(MeshData(np.zeros((0, 3)), np.zeros((0, 3))))
    with pytest.raises(BadInputError, match="lower --face-budget"):
        unwrap(sphere_mesh, max_faces=1000)


@pytest.mark.parametrize("fault,what", [("abort", "crashed"), ("hang", "timed out")])
def test_unwrap_child_crash_is_contained(monkeypatch, fault, what):
    tiny = MeshData(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32),
                    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], np.int32))
    monkeypatch.setenv(CRASH_HOOK_ENV, fault)
    with pytest.raises(BadInputError, match=f"UV unwrap {what} on 4 faces.*lower --face-budget"):
        unwrap(tiny, timeout_s=1.5)
    monkeypatch.delenv(CRASH_HOOK_ENV)
    assert unwrap(tiny, resolution=64).uvs.shape[0] >= 4  # this process is still fine


# ---------------------------------------------------------------------------------------------- whole stage
def test_extract_surface_and_unwrap_end_to_end():
    cams = Cameras.orbit([0, 0, 0], 3.0, 6, width=96, height=96, elevation_deg=20.0)
    surface = extract_surface(SphereSDF(), cams, GeometryConfig(grid_resolution=48, face_budget=1500),
                              trial_resolution=256)
    mesh = unwrap_surface(surface, 256)
    s = mesh.stats
    assert s["faces_marching_cubes"] >= s["faces_after_clean"] >= s["faces_after_decimation"] >= s["faces_final"]
    assert s["faces_after_decimation"] <= 1500 and s["faces_final"] == mesh.num_faces
    assert s["faces_final"] + s["culled_faces"] == s["faces_after_decimation"] and s["culled_faces"] > 0
    assert s["chart_count"] >= 1 and mesh.uvs is not None
    for step in ("marching_cubes", "clean", "decimate", "cull", "unwrap"):
        assert s[f"seconds_{step}"] >= 0
    assert surface.mesh.stats["seconds_surface"] >= s["seconds_marching_cubes"]


# ---------------------------------------------------------------------------------------------- cavities, roughness
class ShellDensity:
    """A NeRF-like density: high only in a shell 0.05 thick at radius 0.5, empty inside (as instant-ngp's
    occupancy grid leaves an unseen interior), optionally with voxel-scale noise on the level set."""

    kind = "density"

    def __init__(self, noise=0.0):
        self.noise = noise
        self.aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])

    def geometry(self, x):
        r = x.norm(dim=-1)
        if self.noise:
            r = r + self.noise * torch.sin(157.0 * x[:, 0]) * torch.sin(163.0 * x[:, 1]) * torch.sin(151.0 * x[:, 2])
        return 100.0 * ((r > 0.45) & (r < 0.5)).float()


def test_enclosed_cavities_are_filled_so_one_surface_remains():
    from neuras_distill.geometry.cleanup import face_components

    mesh = marching_cubes_field(ShellDensity(), 64, level=50.0)
    assert mesh.stats["mc_cavity_voxels"] > 0.8 * (4 / 3 * math.pi * 0.45 ** 3) / (2 / 63) ** 3
    assert len(np.unique(face_components(mesh.faces, mesh.num_vertices))) == 1      # no inner shell
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert r.min() > 0.47 and r.max() < 0.53
    assert signed_volume(mesh.vertices, mesh.faces) == pytest.approx(4 / 3 * math.pi * 0.5 ** 3, rel=0.1)  # solid, not a shell
    # a surface cut open by the box is not a cavity: the sphere of radius 1.2 around the box stays hollow
    big = marching_cubes_field(SphereSDF(radius=1.2, aabb=((-1, -1, -1), (1, 1, 1))), 32)
    assert big.stats["mc_cavity_voxels"] == 0


def test_rough_surfaces_are_measured_and_smoothed():
    from neuras_distill.geometry.cleanup import ROUGH_FOLDED_FRACTION, smooth_rough
    from neuras_distill.geometry.marching import folded_fraction

    smooth = marching_cubes_field(SphereSDF(), 64)
    assert smooth.stats["mc_folded_fraction"] < 1e-3
    assert smooth_rough(smooth).stats["smoothing_steps"] == 0
    rough = marching_cubes_field(ShellDensity(noise=0.03), 96, level=50.0)
    assert rough.stats["mc_folded_fraction"] > ROUGH_FOLDED_FRACTION
    done = smooth_rough(rough)
    assert done.stats["smoothing_steps"] > 0
    assert folded_fraction(done.vertices, done.faces) < 0.25 * rough.stats["mc_folded_fraction"]
    # Taubin keeps the volume: nothing shrinks or disappears
    v0, v1 = signed_volume(rough.vertices, rough.faces), signed_volume(done.vertices, done.faces)
    assert v1 == pytest.approx(v0, rel=0.02)


def test_vertex_normals_are_smooth_across_uv_seams():
    """Vertex normals: the area-weighted face normals around a position, shared by the copies a UV seam makes
    (a cube corner split into three chart copies gets one normal, the diagonal), unit length; on a fine
    sphere they point along the radius."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    vertices, faces = [], []
    for quad in quads:                                   # every side its own chart: corners duplicated
        base = len(vertices)
        vertices += [corners[i] for i in quad]
        faces += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    cube = MeshData(np.array(vertices), np.array(faces))
    assert cube.num_vertices == 24
    normals = cube.vertex_normals()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-6)
    outward = cube.vertices - 0.5
    cos = np.einsum("ij,ij->i", normals, outward / np.linalg.norm(outward, axis=1, keepdims=True))
    assert cos.min() > 0.9                               # near the corner's diagonal (area weights per triangle)
    for corner in corners:                               # ... and one normal for all copies of a corner
        copies = normals[np.all(cube.vertices == corner, axis=1)]
        assert len(copies) == 3 and np.ptp(copies, axis=0).max() == 0
    trimesh = pytest.importorskip("trimesh")
    sphere = trimesh.creation.icosphere(subdivisions=4)
    s = MeshData(sphere.vertices, sphere.faces)
    radial = s.vertices / np.linalg.norm(s.vertices, axis=1, keepdims=True)
    assert np.einsum("ij,ij->i", s.vertex_normals(), radial).min() > 0.999


def test_view_weighted_unwrap_gives_near_faces_more_texels():
    """A 100 m strip whose faces want texel densities falling off 400x along it (a road seen from one end):
    by area every part gets the same texels per m²; with face weights the wanted end gets several times more,
    the mesh is the same surface (same faces, vertices only split at seams), and the planar strip is cut into
    many charts (xatlas alone makes one chart of a plane)."""
    import trimesh

    box = trimesh.creation.box(extents=(100.0, 4.0, 0.5))
    for _ in range(4):
        box = box.subdivide()
    mesh = MeshData(np.asarray(box.vertices, np.float32), np.asarray(box.faces, np.int64))
    centre = mesh.vertices[mesh.faces].mean(axis=1)
    weights = 1.0 / (1.0 + np.abs(centre[:, 0] + 50.0) / 5.0) ** 2
    density = {}
    for name, w in (("area", None), ("weighted", weights)):
        out = unwrap(mesh, resolution=512, face_weights=w)
        assert out.num_faces == mesh.num_faces and out.stats["uv_view_weighted"] == (w is not None)
        tri = out.vertices[out.faces].astype(np.float64)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        assert np.allclose(tri.mean(axis=1), centre, atol=1e-4)          # faces in the same order, same place
        uv = np.abs(uv_face_areas(out.uvs, out.faces))
        assert uv_overlap_fraction(out.uvs, out.faces)[0] < 0.01 and out.uvs.min() >= 0 and out.uvs.max() <= 1
        near, far = centre[:, 0] < -45.0, centre[:, 0] > 40.0
        density[name] = (uv[near].sum() / area[near].sum(), uv[far].sum() / area[far].sum(), out.stats["uv_charts"])
    a_near, a_far, a_charts = density["area"]
    w_near, w_far, w_charts = density["weighted"]
    assert 0.7 < a_near / a_far < 1.4, density
    assert w_near / w_far > 10.0 and w_charts > 10 * a_charts, density
    with pytest.raises(BadInputError, match="face_weights"):
        unwrap(mesh, resolution=64, face_weights=np.zeros(mesh.num_faces))
