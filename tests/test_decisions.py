"""Decisions from measurements: the atlas side from texel density."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.geometry.mesh import MeshData
from neuras_distill.pipeline.decisions import texel_density_resolution
from neuras_distill.render.cameras import Cameras, look_at


def _square(uv_scale: float) -> MeshData:
    """A 1 x 1 square in the z = 0 plane facing +z, its uvs covering uv_scale^2 of the atlas."""
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    return MeshData(v, np.array([[0, 1, 2], [0, 2, 3]], np.int32), ((v[:, :2] + 0.5) * uv_scale).astype(np.float32))


def _camera(distance: float, focal: float, size: int = 400) -> Cameras:
    c2w = look_at(torch.tensor([0.0, 0.0, distance]), torch.zeros(3), torch.tensor([0.0, 1.0, 0.0]))
    return Cameras(c2w[None].float(), focal, focal, size / 2, size / 2, size, size)


def test_one_texel_per_pixel_on_a_square_seen_head_on():
    # the square covers (focal / distance)^2 pixels: 100^2 here (exactly, at its centre's depth)
    side, info = texel_density_resolution(_square(1.0), _camera(2.0, 200.0), pixels_per_texel=1,
                                           multiple=1, lo=1)
    assert info["pixels"] == pytest.approx(100.0 ** 2, rel=1e-6)
    assert info["exact"] == pytest.approx(100.0, rel=1e-6) and side == 100
    # the same pixels on a quarter of the atlas need twice the side; a closer camera (the largest view wins)
    # needs more; rounding goes up to the multiple and the limits hold
    assert texel_density_resolution(_square(0.5), _camera(2.0, 200.0), pixels_per_texel=1, multiple=1, lo=1)[0] == 200
    near, far = _camera(1.0, 200.0), _camera(4.0, 200.0)
    both = Cameras(torch.cat([near.c2w, far.c2w]), 200.0, 200.0, 200.0, 200.0, 400, 400)
    assert texel_density_resolution(_square(1.0), both, pixels_per_texel=1, multiple=1, lo=1)[0] == 200
    # by default a texel spans 2 x 2 pixels of the view that sees it largest: half the side
    assert texel_density_resolution(_square(1.0), both, multiple=1, lo=1)[0] == 100
    assert texel_density_resolution(_square(1.0), _camera(2.0, 200.0))[0] == 128          # lo and multiple of 64
    assert texel_density_resolution(_square(0.004), _camera(2.0, 200.0), hi=2048)[0] == 2048


def test_faces_behind_or_turned_away_count_nothing():
    back = _camera(-2.0, 200.0)                          # behind the square: it faces away
    assert texel_density_resolution(_square(1.0), back, multiple=1, lo=1)[1]["pixels"] == 0.0


def test_training_budget_limits_the_atlas():
    from neuras_distill.pipeline.decisions import training_budget_resolution

    # 1,048,576 samples at 64 per texel feed 16,384 texels: 128^2 on a full atlas, 256^2 when a quarter is used
    assert training_budget_resolution(1 << 20, 1.0, per_texel=64, multiple=1, lo=1) == 128
    assert training_budget_resolution(1 << 20, 0.25, per_texel=64, multiple=1, lo=1) == 256
    assert training_budget_resolution(1 << 22, 1.0, multiple=1, lo=1) == 128           # 256 per texel by default
    assert training_budget_resolution(10, 1.0) == 128


def test_the_training_budget_counts_the_surface_extraction():
    """An automatic plan gets TRAIN_TIME_FRACTION of the surface's stored seconds on top of its share of the
    volume rendering; configured budgets and steps are left alone."""
    from types import SimpleNamespace

    import neuras_distill as nd
    from neuras_distill.pipeline.decisions import TRAIN_TIME_FRACTION
    from neuras_distill.pipeline.stage_results import TrainingPlan
    from neuras_distill.pipeline.stages.geometry import with_surface_time

    auto = TrainingPlan(time_budget_s=28.0, samples_per_step=8192, steps_per_second=95.0, configured_steps=None,
                        max_steps=2660)
    ctx = SimpleNamespace(cfg=nd.load_config("fast"))
    grown = with_surface_time(ctx, auto, 28.0)
    assert grown.time_budget_s == 28.0 + TRAIN_TIME_FRACTION * 28.0
    assert grown.max_steps == int(grown.time_budget_s * 95.0) > auto.max_steps and auto.time_budget_s == 28.0
    assert with_surface_time(ctx, auto, None) is auto                  # a surface stored without its timing
    half = SimpleNamespace(cfg=nd.load_config("fast", overrides={"train": {"budget_share": 0.5}}))
    assert with_surface_time(half, auto, 28.0).time_budget_s == 28.0 + 0.5 * 28.0      # a configured share
    assert nd.load_config("city").train.budget_share == 0.5 and TRAIN_TIME_FRACTION == 1.0
    fixed = TrainingPlan(time_budget_s=None, samples_per_step=8192, steps_per_second=None, configured_steps=500,
                         max_steps=500)
    assert with_surface_time(ctx, fixed, 28.0) is fixed
    budgeted = SimpleNamespace(cfg=nd.load_config("fast", overrides={"train": {"time_budget_s": 30.0}}))
    assert with_surface_time(budgeted, auto, 28.0) is auto
