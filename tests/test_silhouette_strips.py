"""Where the soft-silhouette pass runs (playback/silhouette_strips.py): the screen tiles along the mesh's silhouette
and boundary edges contain every pixel the pass changes, and not much more."""

import numpy as np
import pytest

from neuras_distill.geometry.mesh import MeshData
from neuras_distill.playback.projection import camera_near_far, mesh_bounds, mvp_for
from neuras_distill.playback.silhouette import layer_coverage, silhouette_edges
from neuras_distill.playback.silhouette_strips import TILE_PX, SilhouetteEdges
from neuras_distill.render.cameras import Cameras, look_at
from test_two_layer import _sphere, cameras, gl, two_spheres

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _seamed_sphere(radius: float = 0.5) -> MeshData:
    """An icosphere whose vertices are split along x = 0 (as xatlas splits them along UV seams)."""
    v, f, uv = _sphere(radius)
    f = f.copy()
    right = v[f].mean(axis=1)[:, 0] > 0
    copies = np.arange(len(v)) + len(v)
    f[right] = copies[f[right]]
    return MeshData(np.concatenate([v, v]), f, np.concatenate([uv, uv]))


def _pixels_of(mask: np.ndarray, height: int, width: int) -> np.ndarray:
    """(H, W) bool, row 0 = top, of a tile mask (row 0 = bottom)."""
    up = np.repeat(np.repeat(mask, TILE_PX, axis=0), TILE_PX, axis=1)[:height, :width]
    return up[::-1]


def _tiles_and_edges(mesh: MeshData, cams: Cameras, i: int):
    from neuras_distill.playback.rasterize import rasterize_gbuffer

    edges = SilhouetteEdges(mesh.vertices, mesh.faces)
    near, far = camera_near_far(mesh_bounds(mesh.vertices), cams, i)
    mask = edges.tiles(cams.c2w[i, :3, 3].double().numpy(), mvp_for(cams, i, near, far), cams.width, cams.height)
    gbuffer = rasterize_gbuffer(mesh, cams[i])
    layers = layer_coverage(gbuffer.face_id[0], mesh.core_faces)      # two layers: the core's seam is an edge
    return _pixels_of(mask, cams.height, cams.width), silhouette_edges(layers), gbuffer.coverage[0]


def test_seams_are_welded_and_a_closed_mesh_has_no_boundary():
    seamed = _seamed_sphere()
    edges = SilhouetteEdges(seamed.vertices, seamed.faces)
    assert len(edges.always) == 0                             # the split along x = 0 is not a boundary
    eye = np.array([0.0, -3.0, 0.0])
    border = edges.border_edges(eye)
    assert 0 < len(border) < 0.1 * edges.num_edges             # the silhouette: a thin loop of edges
    mid = edges.vertices[edges.edge_ends[border]].mean(axis=1)
    assert np.abs(mid[:, 1]).max() < 0.15                      # around the sphere's rim as seen from -y
    v, f, _ = _sphere(0.5)
    half = f[v[f].mean(axis=1)[:, 2] > 0]                       # an open hemisphere: its rim is a boundary
    assert len(SilhouetteEdges(v, half).always) > 10


@gl
@pytest.mark.gl
@pytest.mark.parametrize("kind, share", [("seamed sphere", 0.4), ("two layers", 0.75), ("open hemisphere", 0.75)])
def test_tiles_hold_every_pixel_the_pass_changes(kind, share):
    if kind == "seamed sphere":
        mesh = _seamed_sphere()
    elif kind == "two layers":
        mesh = two_spheres()
    else:
        v, f, uv = _sphere(0.5)
        mesh = MeshData(v, f[v[f].mean(axis=1)[:, 2] > 0], uv)
    cams = cameras(3, 320)
    for i in range(len(cams)):
        tiles, edges, coverage = _tiles_and_edges(mesh, cams, i)
        assert edges.sum() > 100
        assert not (edges & ~tiles).any()                       # every pixel the pass changes is in a tile
        ys, xs = np.nonzero(coverage)
        box = (ys.max() - ys.min() + 1) * (xs.max() - xs.min() + 1)
        assert tiles.sum() < share * box               # and the tiles are a fraction of the box (two layers: 2 rims)


@gl
@pytest.mark.gl
def test_a_camera_beside_the_mesh_gets_finite_tiles():
    """Half of the sphere lies behind the camera: its border edges are clipped at the camera plane."""
    import torch

    mesh = _seamed_sphere()
    eye = np.array([0.0, -0.6, 0.0])
    c2w = look_at(torch.tensor(eye), torch.tensor([1.0, -0.35, 0.0]), torch.tensor([0.0, 0.0, 1.0]))
    cams = Cameras(c2w[None], 60.0, 60.0, 48.0, 32.0, 96, 64)
    edges = SilhouetteEdges(mesh.vertices, mesh.faces)
    mvp = mvp_for(cams, 0, 0.01, 10.0)
    behind = (np.c_[edges.vertices, np.ones(len(edges.vertices))] @ mvp.T)[:, 3] <= 0
    assert behind.any() and not behind.all()
    seg = edges.project_border(eye, mvp, 96, 64)
    assert len(seg) > 0 and np.isfinite(seg).all()
    quads = SilhouetteEdges.tile_quads(edges.tiles(eye, mvp, 96, 64), 96, 64)
    assert len(quads) > 0 and np.isfinite(quads).all() and np.abs(quads).max() <= 1.0 + 1e-6


def test_tile_quads_are_the_runs_of_each_row():
    mask = np.zeros((3, 5), bool)
    mask[0, 1:3] = True
    mask[0, 4] = True
    mask[2, :] = True
    quads = SilhouetteEdges.tile_quads(mask, 5 * TILE_PX - 3, 3 * TILE_PX).reshape(-1, 6, 2)
    assert len(quads) == 3                                       # two runs in row 0, one in row 2
    w, h = 5 * TILE_PX - 3, 3 * TILE_PX
    px = (quads + 1.0) * np.array([w / 2, h / 2])
    spans = sorted((round(q[:, 0].min()), round(q[:, 0].max()), round(q[:, 1].min())) for q in px)
    assert spans == [(0, w, 2 * TILE_PX), (TILE_PX, 3 * TILE_PX, 0), (4 * TILE_PX, w, 0)]   # clamped to the width
