"""Near misses (the field shows a foreground surface the mesh missed) stay out of the skyboxes' training:
which pixels they are (``rules.near_miss_pixels``) and what leaving them out does to the skybox (``fit``)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.config import TrainConfig
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.skybox import SkyboxLayers, SkyboxModel
from neuras_distill.neural.train import fit
from neuras_distill.neural.train_batches import TrainingPixels
from neuras_distill.pipeline.rules import near_miss_pixels


def _rays(h, w):
    """One camera at (0, 0, -5) looking along +z: its centre (1, 3) and unit directions (1, H, W, 3)."""
    ys, xs = np.meshgrid(np.linspace(-0.3, 0.3, h), np.linspace(-0.3, 0.3, w), indexing="ij")
    d = np.stack([xs, ys, np.ones_like(xs)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return np.array([[0.0, 0.0, -5.0]]), d[None]


def test_near_misses_are_uncovered_pixels_whose_surface_lies_in_the_foreground_box():
    h, w = 4, 5
    depth = np.zeros((1, h, w), np.float32)
    depth[0, 0, :] = 5.0                  # hits near z = 0: inside the box
    depth[0, 1, :] = 40.0                 # far background beyond the box
    depth[0, 2, :] = 5.0
    coverage = np.zeros((1, h, w), bool)
    coverage[0, 2, :] = True              # the mesh covers row 2
    near = near_miss_pixels(depth, np.zeros_like(depth), coverage, *_rays(h, w),
                            torch.tensor([[-2.0, -2.0, -1.0], [2.0, 2.0, 1.0]]))
    assert near.shape == (1, h, w) and near.dtype == bool
    assert near[0, 0].all() and not near[0, 1:].any()      # row 3: depth 0, the field shows nothing opaque


def test_a_fringe_counts_as_a_near_miss_only_beside_the_mesh():
    """Where the field only reaches its fringe opacity inside the box, the pixel is a near miss next to the mesh's
    silhouette (a soft edge of a part the mesh holds) and sky far from it (haze the sky shows through)."""
    h, w = 3, 100                          # reach: 2% of 100 = 2 pixels
    surface = np.zeros((1, h, w), np.float32)
    fringe = np.full((1, h, w), 5.0, np.float32)           # the fringe level is reached inside the box everywhere
    coverage = np.zeros((1, h, w), bool)
    coverage[0, :, :10] = True                             # the mesh covers the left columns
    surface[0, 1, 80] = 5.0                                # one half-opaque pixel far from the mesh
    near = near_miss_pixels(surface, fringe, coverage, *_rays(h, w),
                            torch.tensor([[-2.0, -2.0, -1.0], [2.0, 2.0, 1.0]]))
    assert near[0, :, 10:12].all()                         # within 2 pixels of the mesh
    assert not near[0, :, 12:80].any() and not near[0, :, 81:].any()
    assert near[0, 1, 80] and not near[0, 0, 80]           # 0.5 opacity counts anywhere
    assert not near[0, :, :10].any()                       # covered pixels are never near misses


def _train_sky(sky_pixels):
    h = w = 16
    torch.manual_seed(0)
    model = NeuralTextureModel(8, 8, feature_dim=4, num_codes=8, hidden=8, use_viewdir=False)
    sky = SkyboxModel(SkyboxLayers((0, 0, 0), [3.0, 6.0], 4), feature_dim=4, num_codes=8, hidden=8)
    d = torch.as_tensor(_rays(h, w)[1], dtype=torch.float32)
    coverage = np.zeros((1, h, w), bool)
    coverage[0, :, :6] = True                                   # the mesh: the left columns
    targets = np.empty((1, h, w, 3), np.float32)
    targets[...] = (0.2, 0.4, 0.9)                              # sky
    targets[0, :, :6] = (0.5, 0.5, 0.5)                         # mesh
    targets[0, 4:10, 6:9] = (0.9, 0.1, 0.1)                     # a lamp the mesh missed, next to it
    uv = np.full((1, h, w, 2), 0.5, np.float32)
    dirs = d[..., :model.view_columns] if model.view_columns else d[..., :0]
    fit(model, TrainingPixels(uv, coverage, dirs.numpy(), targets, origins=np.zeros((1, 3), np.float32),
                              sky_pixels=sky_pixels),
        steps=300, config=TrainConfig(batch_patches=4, patch=8), progress=False, skybox=sky)
    with torch.no_grad():
        rgb, _ = sky(torch.zeros(18, 3), d[0, 4:10, 6:9].reshape(-1, 3))
    return rgb


@pytest.mark.slow
def test_a_skybox_left_out_of_near_misses_keeps_the_sky_there():
    near = np.zeros((1, 16, 16), bool)
    near[0, 4:10, 6:9] = True
    coverage = np.zeros((1, 16, 16), bool)
    coverage[0, :, :6] = True
    left_out = _train_sky(~coverage & ~near)
    trained_on = _train_sky(None)
    blue = torch.tensor([0.2, 0.4, 0.9])
    kept = (left_out - blue).abs().max(dim=-1).values.median()
    smeared = (trained_on - blue).abs().max(dim=-1).values.median()
    assert kept < 0.12, kept                                       # the sky stays sky where the lamp was
    assert smeared > kept + 0.1, (smeared, kept)                   # trained on the lamp, the sky turns red


def test_the_skyboxes_share_of_content_inside_the_box_is_recorded():
    """Uncovered pixels whose box content is partly opaque (below the near-miss level) are still the skyboxes'
    to learn; the decision record says what share of their pixels they are."""
    from neuras_distill.pipeline.choices import Decisions, sky_training_pixels

    h, w = 4, 5
    depth = np.zeros((1, h, w), np.float32)
    coverage = np.zeros((1, h, w), bool)
    coverage[0, 3, :] = True                              # 15 uncovered pixels, none a near miss
    opacity = np.zeros((1, h, w), np.float32)
    opacity[0, 0, :] = 0.3                                # 5 of them: 30% opaque inside the box
    opacity[0, 1, :2] = 0.1                               # faint haze: not counted
    record = Decisions()
    learnt = sky_training_pixels(depth, depth, coverage, *_rays(h, w),
                                 torch.tensor([[-2.0, -2.0, -1.0], [2.0, 2.0, 1.0]]), record, opacities=opacity)
    assert int(learnt.sum()) == 15
    entry = next(d for d in record.to_json() if d["component"] == "skybox pixels inside the box")
    assert entry["measured"]["sky_inside_box_pixels"] == 5
    assert entry["measured"]["sky_inside_box_fraction"] == pytest.approx(5 / 15)


def test_a_soft_edge_with_something_opaque_behind_it_is_given_back_to_the_skyboxes():
    """Near misses by their fringe alone (under 0.5 opacity inside the box, within 2% of the width of the mesh)
    are asked whether their whole ray reaches 0.5 beyond the box; those that do show mostly what lies behind,
    and the skyboxes learn them. Near misses by a surface inside the box are never asked."""
    from neuras_distill.pipeline.choices import Decisions, sky_training_pixels

    h, w = 6, 100                                            # the fringe's reach: 2 pixels
    surface = np.zeros((1, h, w), np.float32)
    surface[0, 0, 51] = 5.0                                  # a surface inside the box at z = 0: a near miss
    fringe = np.full((1, h, w), 5.0, np.float32)            # a fringe inside the box everywhere
    coverage = np.zeros((1, h, w), bool)
    coverage[0, :, :50] = True                               # the mesh: the left half
    asked = []

    def seen_through(candidates):
        asked.append(candidates.copy())
        behind = np.zeros_like(candidates)
        behind[0, 2:, :] = candidates[0, 2:, :]              # the ground beyond the box: rows 2 and below
        return behind

    box = torch.tensor([[-2.0, -2.0, -1.0], [2.0, 2.0, 1.0]])
    plain = sky_training_pixels(surface, fringe, coverage, *_rays(h, w), box, Decisions())
    record = Decisions()
    learnt = sky_training_pixels(surface, fringe, coverage, *_rays(h, w), box, record, seen_through=seen_through)
    assert not plain[0, :, 50:52].any() and plain[0, :, 52:].all()      # beside the mesh: fringe near misses
    assert not asked[0][0, 0, 51] and asked[0][0, 1, 51] and asked[0][0, :, 50].all()
    assert learnt[0, 2:, 50:52].all() and not learnt[0, :2, 50:52].any()  # given back where something lies behind
    assert not learnt[:, :, :50].any() and learnt[0, :, 52:].all()
    entry = next(d for d in record.to_json() if d["component"] == "skybox training behind soft edges")
    assert entry["measured"]["seen_through_pixels"] == int((learnt & ~plain).sum()) == 8


def test_skyboxes_that_hold_ground_get_the_larger_codebook():
    from neuras_distill.pipeline.choices import Decisions, skybox_codes
    from neuras_distill.pipeline.rules import SKY_CODES, SKY_GROUND_SHARE

    record = Decisions()
    assert skybox_codes(SKY_GROUND_SHARE + 0.05, record) == SKY_CODES[1] == 16384
    assert skybox_codes(SKY_GROUND_SHARE - 0.11, record) == SKY_CODES[0] == 4096     # the street: 9% below
    kept, left = [d for d in record.to_json() if d["component"] == "a larger skybox codebook"]
    assert kept["kept"] and kept["measured"]["codes"] == 16384
    assert not left["kept"] and left["measured"]["codes"] == 4096
