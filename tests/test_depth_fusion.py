"""Meshing a trained NeRF's surface from its depth maps (geometry/depth_fusion.py) instead of a density level
set full of unsupervised interior foam."""

import numpy as np
import pytest
import torch

from neuras_distill.config import GeometryConfig
from neuras_distill.geometry.depth_fusion import fused_depth_sdf
from neuras_distill.geometry.grid import grid_spec
from neuras_distill.geometry.marching import marching_cubes_field, marching_cubes_grid, mesh_handles

FOAM_HANDLES = 100          # the foam ball's level set has far more
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.volume import VolumeRenderer

RADIUS = 0.3


class FoamBall:
    """A density ball whose 0.03-thick crust is what cameras see; inside, a gyroid labyrinth crosses the
    level everywhere and reaches the crust (what a NeRF leaves where no ray was supervised)."""

    kind = "density"
    aabb = torch.tensor([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])

    def geometry(self, x):
        r = x.norm(dim=-1)
        a = 40.0 * x
        gyroid = (torch.sin(a[:, 0]) * torch.cos(a[:, 1]) + torch.sin(a[:, 1]) * torch.cos(a[:, 2])
                  + torch.sin(a[:, 2]) * torch.cos(a[:, 0]))
        crust = 400.0 * ((r > RADIUS - 0.03) & (r < RADIUS) & (gyroid > -1.2)).float()    # with pores
        foam = 200.0 * (gyroid > 0).float()
        return torch.where(r < RADIUS - 0.02, foam, crust)

    def radiance(self, x, d):
        return torch.full_like(x, 0.5)


def _views(field, n=12, size=48):
    cams = Cameras.orbit((0, 0, 0), 1.6, n, width=size, height=size, fov_deg=40.0, elevation_deg=(-40.0, 50.0))
    teacher = VolumeRenderer(field, num_steps=192)
    outs = [teacher.render(cams, i, crossings=True) for i in range(len(cams))]
    return cams, np.stack([o["surface_depth"] for o in outs]), np.stack([o["opacity"] for o in outs])


@pytest.mark.slow
def test_surface_depth_is_where_opacity_reaches_half():
    cams, depth, opacity = _views(FoamBall(), n=1, size=16)
    centre = depth[0, 8, 8]
    # the crust's optical depth is 12: opacity 0.5 is reached ln2/400 past the entry point; the march resolves
    # it to about a step (the box diagonal / 192)
    assert abs(centre - (1.6 - RADIUS + np.log(2) / 400.0)) < 1.5 * np.sqrt(3.0) / 192
    assert (depth[opacity < 0.5] == 0).all()


@pytest.mark.slow
def test_fused_depth_meshes_the_seen_surface_without_the_interior_foam():
    field = FoamBall()
    foam = marching_cubes_field(field, 48)
    assert mesh_handles(foam) > FOAM_HANDLES                                  # the level set is foam
    inner = np.linalg.norm(foam.vertices, axis=1) < RADIUS - 0.06
    assert inner.mean() > 0.3

    cams, depth, opacity = _views(field)
    spec = grid_spec(field.aabb, 48)
    sdf, stats = fused_depth_sdf(spec.origin, spec.spacing, spec.shape, cams, depth, opacity,
                                 truncation=6 * float(spec.spacing.max()))
    mesh = marching_cubes_grid(sdf, spec.origin, spec.spacing, "sdf", 0.0)
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert mesh_handles(mesh) == 0
    assert abs(np.median(r) - RADIUS) < 0.5 * float(spec.spacing.max())
    assert np.percentile(r, 1) > RADIUS - 2 * float(spec.spacing.max())        # nothing inside but pores
    assert stats["fused_hidden_fraction"] > 0.01                               # the core, deeper than the truncation


@pytest.mark.slow
def test_marching_cubes_meshes_the_fused_surface_when_asked():
    field = FoamBall()
    cams, depth, opacity = _views(field)

    def fusion(spec, fringe=False):
        return fused_depth_sdf(spec.origin, spec.spacing, spec.shape, cams, depth, opacity,
                               truncation=6 * float(spec.spacing.max()))

    mesh = marching_cubes_field(field, 64, depth_fusion=fusion)
    assert mesh.stats["mc_density_handles"] > FOAM_HANDLES                  # what the level set would have been
    assert mesh.stats["mc_surface_from"] == "fused depth maps"
    assert mesh.stats["mc_handles"] == 0
    assert abs(np.median(np.linalg.norm(mesh.vertices, axis=1)) - RADIUS) < 0.01


def _extract(field, monkeypatch, fail_first_unwrap: bool):
    from neuras_distill.geometry import extract
    from neuras_distill.geometry.unwrap import UnwrapFailed

    cams, depth, opacity = _views(field, n=8, size=32)
    calls = []
    real = extract.unwrap

    def unwrap(mesh, **kw):
        calls.append(mesh.num_faces)
        if fail_first_unwrap and len(calls) == 1:
            raise UnwrapFailed("UV unwrap timed out on the level set (simulated)")
        return real(mesh, **kw)

    monkeypatch.setattr(extract, "unwrap", unwrap)
    config = GeometryConfig(grid_resolution=48, face_budget=2000, unwrap_timeout_s=60)
    surface = extract.extract_surface(field, cams, config, trial_resolution=128, field_depth=(depth, depth, opacity))
    mesh = extract.unwrap_surface(surface, 128, unwrap_timeout_s=60)
    return mesh, calls


@pytest.mark.slow
def test_a_level_set_that_unwraps_is_kept(monkeypatch):
    from neuras_distill.scenes.analytic import SphereSDF

    mesh, calls = _extract(SphereSDF(radius=RADIUS).density(), monkeypatch, fail_first_unwrap=False)
    assert len(calls) == 1 and "mc_surface_from" not in mesh.stats
    assert mesh.stats["mc_density_handles"] == 0


@pytest.mark.slow
def test_a_level_set_xatlas_cannot_unwrap_is_meshed_from_the_depth_maps(monkeypatch):
    from neuras_distill.scenes.analytic import SphereSDF

    mesh, calls = _extract(SphereSDF(radius=RADIUS).density(), monkeypatch, fail_first_unwrap=True)
    assert len(calls) == 2
    assert mesh.stats["mc_surface_from"] == "fused depth maps"
    assert "simulated" in mesh.stats["level_set_unwrap_failure"]
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert np.percentile(r, 5) > RADIUS - 0.05 and mesh.uvs is not None


@pytest.mark.slow
def test_a_foam_level_set_is_meshed_from_the_depth_maps_before_any_unwrap(monkeypatch):
    """The foam ball's level set (pores in its crust, a labyrinth inside) is judged before it is unwrapped:
    the fused depths replace it and only they are unwrapped."""
    mesh, calls = _extract(FoamBall(), monkeypatch, fail_first_unwrap=False)
    print({k: v for k, v in mesh.stats.items() if k.startswith(("level_set", "fused_depths"))})
    assert len(calls) == 1 and mesh.stats["surface_from_depths"] is True
    assert mesh.stats["mc_surface_from"] == "fused depth maps"
    assert mesh.stats["level_set_defect"] in ("perforated", "tangled")
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert np.percentile(r, 5) > RADIUS - 0.05 and mesh.uvs is not None


@pytest.mark.slow
def test_a_tangled_level_set_is_meshed_from_the_depth_maps(monkeypatch):
    """A decimated level set whose core is tangled (over ``TANGLED_FOLDED_FRACTION`` of its adjacent faces
    folded: simulated here on the sphere's level set) is meshed again from the fused depths, which are kept
    because they are less folded and miss no more opaque pixels; the smooth sphere alone is kept as is (above)."""
    from neuras_distill.geometry import extract
    from neuras_distill.scenes.analytic import SphereSDF

    real = extract.core_folded_fraction
    seen = []

    def folded(mesh):
        seen.append(real(mesh))
        return 0.5 if len(seen) == 1 else seen[-1]

    monkeypatch.setattr(extract, "core_folded_fraction", folded)
    mesh, calls = _extract(SphereSDF(radius=RADIUS).density(), monkeypatch, fail_first_unwrap=False)
    assert len(calls) == 1 and seen[0] < 0.01 and seen[1] < extract.TANGLED_FOLDED_FRACTION   # one unwrap: the kept one
    assert mesh.stats["level_set_defect"] == "tangled" and mesh.stats["surface_from_depths"] is True
    assert mesh.stats["mc_surface_from"] == "fused depth maps" and mesh.stats["level_set_folded"] == 0.5
    r = np.linalg.norm(mesh.vertices, axis=1)
    assert 0 < mesh.stats["fused_outset"] < 0.03                           # half a voxel out (extract.py)
    assert abs(np.median(r) - RADIUS - mesh.stats["fused_outset"]) < 0.03


def test_a_fused_surface_is_moved_half_a_voxel_outwards_along_its_normals():
    """``extract.outset_fused_surface``: every vertex of a sphere moves ``FUSED_OUTSET_VOXELS`` voxels out
    along its normal (the fused surface's rims otherwise miss a pixel against the field's silhouette), faces and
    uvs untouched; without a voxel size nothing moves."""
    from neuras_distill.geometry.extract import FUSED_OUTSET_VOXELS, outset_fused_surface
    from neuras_distill.geometry.marching import marching_cubes_field
    from neuras_distill.scenes.analytic import SphereSDF

    sphere = marching_cubes_field(SphereSDF(radius=RADIUS), 40)
    voxel = float(sphere.stats["voxel_size"])
    moved = outset_fused_surface(sphere)
    grown = np.linalg.norm(moved.vertices, axis=1) - np.linalg.norm(sphere.vertices, axis=1)
    assert FUSED_OUTSET_VOXELS == 0.5 and moved.stats["fused_outset"] == pytest.approx(0.5 * voxel)
    assert grown == pytest.approx(np.full_like(grown, 0.5 * voxel), abs=0.02 * voxel)
    assert np.array_equal(moved.faces, sphere.faces)
    sphere.stats.pop("voxel_size")
    assert outset_fused_surface(sphere) is sphere


class HazySlab:
    """A floor of haze, 0.1 thick: opacity 0.33 seen from straight above, 0.6 at 20 degrees (a partly trained
    nerfacto ground is such a haze, opaque in some views and not in others)."""

    kind = "density"
    aabb = torch.tensor([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])

    def geometry(self, x):
        return 4.0 * (x[:, 2].abs() < 0.05).float()

    def radiance(self, x, d):
        return torch.full_like(x, 0.5)


def _floor_cover(mesh, half=0.3, bins=12) -> float:
    """Share of a (bins x bins) grid over the floor's central square holding a mesh vertex near z = 0."""
    v = mesh.vertices[(np.abs(mesh.vertices[:, 2]) < 0.15) & (np.abs(mesh.vertices[:, :2]) < half).all(1)]
    filled, _, _ = np.histogram2d(v[:, 0], v[:, 1], bins=bins, range=[[-half, half], [-half, half]])
    return float((filled > 0).mean())


@pytest.mark.slow
def test_a_hazy_floor_is_a_surface_where_some_views_see_it_faint():
    """``faint``: pixels above the faint level vote for a surface at their fringe depth, not for free space,
    so a floor opaque only at grazing views is meshed (``extract.FAINT_SURFACE_OPACITY``)."""
    field = HazySlab()
    cams = Cameras.orbit((0, 0, 0), 1.4, 12, width=40, height=40, fov_deg=40.0, elevation_deg=(15.0, 85.0))
    teacher = VolumeRenderer(field, num_steps=192)
    outs = [teacher.render(cams, i, crossings=True) for i in range(len(cams))]
    surface, fringe, opacity = (np.stack([o[k] for o in outs]) for k in ("surface_depth", "fringe_depth", "opacity"))
    assert (opacity > 0.5).mean() > 0.1 and ((opacity > 0.3) & (opacity <= 0.5)).mean() > 0.1   # both kinds
    spec = grid_spec(field.aabb, 40)
    covers = []
    for faint in (None, (fringe, 0.3)):
        sdf, stats = fused_depth_sdf(spec.origin, spec.spacing, spec.shape, cams, surface, opacity,
                                     truncation=6 * float(spec.spacing.max()), faint=faint)
        covers.append(_floor_cover(marching_cubes_grid(sdf, spec.origin, spec.spacing, "sdf", 0.0)))
        assert (stats["fused_faint_pixels"] > 0.1) == (faint is not None), stats
    assert covers[0] < 0.2 and covers[1] > 0.95, covers


def test_faint_regions_keep_a_haze_and_drop_a_silhouettes_one_pixel_band():
    from neuras_distill.geometry.depth_fusion import FAINT_MIN_WIDTH_PX, faint_regions

    opacity = np.zeros((20, 20), dtype=np.float32)
    opacity[2:10, 2:10] = 0.4                      # a haze 8 pixels wide
    opacity[12:18, 12:18] = 1.0                    # an object...
    opacity[11, 12:18] = 0.4                       # ...whose silhouette covers a row of pixels in part
    opacity[5, 15] = 0.45                          # one faint speck
    mask = faint_regions(opacity, 0.3, 0.5)
    assert FAINT_MIN_WIDTH_PX >= 2
    assert mask[2:10, 2:10].all() and mask.sum() == 64
    assert not mask[11].any() and not mask[5, 15] and not mask[12:18, 12:18].any()
