"""Decisions from measurements: the atlas side from texel density."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.geometry.mesh import MeshData
from neuras_distill.pipeline.rules import texel_density_resolution
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
    from neuras_distill.pipeline.rules import training_budget_resolution

    # 1,048,576 samples at 64 per texel feed 16,384 texels: 128^2 on a full atlas, 256^2 when a quarter is used
    assert training_budget_resolution(1 << 20, 1.0, per_texel=64, multiple=1, lo=1) == 128
    assert training_budget_resolution(1 << 20, 0.25, per_texel=64, multiple=1, lo=1) == 256
    assert training_budget_resolution(1 << 22, 1.0, multiple=1, lo=1) == 128           # 256 per texel by default
    assert training_budget_resolution(10, 1.0) == 128


def test_a_run_budget_leaves_training_what_the_earlier_stages_and_the_evaluation_leave():
    """--time-budget caps the whole run: training gets the budget less the time spent and the evaluation's
    estimate; a budget already spent is refused with one line naming a budget that would do."""
    from neuras_distill.errors import BadInputError
    from neuras_distill.pipeline.rules import evaluation_seconds, run_budget_left

    assert evaluation_seconds(60.0, 10**6, 2 * 10**5) == pytest.approx(12.0)     # the teacher's seconds per pixel
    assert run_budget_left(300.0, 100.0, 40.0) == 160.0
    with pytest.raises(BadInputError, match=r"--time-budget 120: the stages before training took 100 s and the "
                                            r"evaluation needs about 40 s.*pass --time-budget 270 or more"):
        run_budget_left(120.0, 100.0, 40.0)


def test_the_report_names_the_rule_that_stopped_training():
    from neuras_distill.pipeline.report_json import training_stop
    from neuras_distill.pipeline.stage_results import TrainingPlan

    auto = TrainingPlan(time_budget_s=600.0, samples_per_step=8192, steps_per_second=100.0, configured_steps=None,
                        max_steps=60000, steps=7009, needed_steps=7009, used_texels=28032)
    log = {"steps": 7009, "stopped_by": "steps", "seconds": 70.0, "held_back": []}
    assert training_stop(auto, log) == {"rule": "texel rule", "steps": 7009,
                                         "why": "7009 steps gave every used texel about 2048 training samples"}
    plateau = dict(log, steps=6475, stopped_by="plateau", held_back=[[6300, 31.83], [6475, 31.80]])
    assert training_stop(auto, plateau)["rule"] == "plateau"
    assert "best 31.83 dB at step 6300; 6475 of the 7009 planned steps" in training_stop(auto, plateau)["why"]
    late = dict(log, steps=5000, stopped_by="time_budget", seconds=600.2)
    assert training_stop(auto, late) == {"rule": "time budget", "steps": 5000,
                                         "why": "the time budget ran out after 600 s, at step 5000 of 7009"}
    short = TrainingPlan(time_budget_s=20.0, samples_per_step=8192, steps_per_second=100.0, configured_steps=None,
                         max_steps=2000, steps=2000, needed_steps=7009, used_texels=28032)
    assert training_stop(short, dict(log, steps=2000))["rule"] == "time budget"
    fixed = TrainingPlan(time_budget_s=None, samples_per_step=8192, steps_per_second=None, configured_steps=300,
                         max_steps=300, steps=300, needed_steps=7009, used_texels=28032)
    assert training_stop(fixed, dict(log, steps=300)) == {"rule": "configured steps", "steps": 300,
                                                          "why": "the 300 configured steps ran"}


def test_the_coarse_level_is_kept_only_where_texels_are_short_of_samples():
    from neuras_distill.pipeline.choices import Decisions, coarse_level
    from neuras_distill.pipeline.rules import TARGET_SAMPLES_PER_TEXEL
    from neuras_distill.pipeline.stage_results import TrainingPlan

    def plan(steps):
        return TrainingPlan(time_budget_s=None, samples_per_step=8192, steps_per_second=None,
                            configured_steps=None, steps=steps, used_texels=28032)

    full = 28032 * TARGET_SAMPLES_PER_TEXEL // 8192          # 7008 steps: 2048 samples per texel exactly
    record = Decisions()
    assert coarse_level(8, plan(full), record) == 1
    assert coarse_level(8, plan(full - 1), record) == 8
    assert coarse_level(1, plan(10), record) == 1
    left, kept, off = record.items
    assert not left.kept and "2048 samples" in left.reason and left.measured["samples_per_texel"] == 2048
    assert kept.kept and "8 times coarser" in kept.reason and kept.measured["samples_per_texel"] < 2048
    assert not off.kept and "coarse_factor 1" in off.reason


def test_only_choices_records_decisions():
    """Every keep / leave-out decision is recorded in ``pipeline/choices.py`` (docs/architecture.md): a stage asks
    choices, which records; no other module calls ``Decisions.keep`` or ``Decisions.leave_out``."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    home = root / "neuras_distill" / "pipeline" / "choices.py"
    elsewhere = []
    for path in sorted([*(root / "neuras_distill").rglob("*.py"), *(root / "adapters").rglob("*.py")]):
        if path == home:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                    and node.func.attr in ("keep", "leave_out")):
                elsewhere.append(f"{path.relative_to(root)}:{node.lineno}")
    assert elsewhere == []
    assert "record.keep(" in home.read_text() and "record.leave_out(" in home.read_text()


def test_only_the_plan_module_writes_the_training_plan():
    """``TrainingPlan`` is frozen (an attribute write raises) and ``pipeline/stages/plan.py`` alone makes or changes
    one: no other module calls ``TrainingPlan(...)`` or ``replace(plan, ...)`` (its ``load`` reads a stored one)."""
    import ast
    import dataclasses
    from pathlib import Path

    from neuras_distill.pipeline.stage_results import TrainingPlan

    plan = TrainingPlan(time_budget_s=None, samples_per_step=1, steps_per_second=None, configured_steps=10)
    with pytest.raises(dataclasses.FrozenInstanceError):
        plan.steps = 3
    root = Path(__file__).resolve().parent.parent
    home = root / "neuras_distill" / "pipeline" / "stages" / "plan.py"
    elsewhere = []
    for path in sorted([*(root / "neuras_distill").rglob("*.py"), *(root / "adapters").rglob("*.py")]):
        if path == home:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if not isinstance(node, ast.Call):
                continue
            name = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", "")
            makes = name == "TrainingPlan"
            changes = name == "replace" and any(isinstance(a, ast.Name) and "plan" in a.id for a in node.args[:1])
            if makes or changes:
                elsewhere.append(f"{path.relative_to(root)}:{node.lineno}")
    assert elsewhere == []
    assert "replace(plan," in home.read_text() and "TrainingPlan(" in home.read_text()


def test_skyboxes_that_hold_ground_get_finer_depth_layers():
    """``skybox.layers`` 0: the share of the skyboxes' pixels looking more than 2 degrees below the horizon picks 8
    layers from 20% (checker360: 25%, orbit360 about half; the street 9% keeps 4), and the decision says so."""
    from neuras_distill.pipeline.choices import Decisions, skybox_layers
    from neuras_distill.pipeline.rules import below_horizon_share

    elevation = np.radians(np.linspace(-30.0, 30.0, 61))                 # one view, 61 x 1 rays, z up
    dirs = np.stack([np.cos(elevation), np.zeros_like(elevation), np.sin(elevation)], -1).reshape(1, 61, 1, 3)
    pixels = np.ones((1, 61, 1), bool)
    assert below_horizon_share(dirs, pixels, [0.0, 0.0, 2.0]) == pytest.approx(28 / 61)       # -30 .. -3 degrees
    pixels[0, :31] = False                                                # only the level and upward rays
    assert below_horizon_share(dirs, pixels, [0.0, 0.0, 1.0]) == 0.0
    assert below_horizon_share(dirs, np.zeros_like(pixels), [0.0, 0.0, 1.0]) == 0.0
    record = Decisions()
    assert skybox_layers(0.25, record) == 8 and skybox_layers(0.09, record) == 4
    kept, left = record.items
    assert kept.kept and "25% of the pixels the skyboxes learn look below the horizon" in kept.reason
    assert not left.kept and left.measured["layers"] == 4


def test_skyboxes_that_hold_a_ground_lie_on_it_at_each_rings_median_height():
    """``rules.ground_heights``: each layer's floor is the median height of the hits in its ring (``r_{l-1} <=
    max(|x|, |y|) < r_l``, z up); a ring with too few takes its nearest filled neighbour's; no floor rises above
    the lowest camera. ``choices.skybox_ground`` keeps it for a ground, however faint, not for a sky or haze."""
    from neuras_distill.pipeline.choices import Decisions, skybox_ground
    from neuras_distill.pipeline.rules import GROUND_MIN_HITS, ground_heights

    rng = np.random.default_rng(0)
    radii = np.array([4.0, 8.0, 16.0])

    def ring(lo, hi, z, n):
        r, a = rng.uniform(lo, hi, n), rng.uniform(0, 2 * np.pi, n)
        p = np.stack([r * np.cos(a), r * np.sin(a), np.full(n, z)], 1)
        return p[(np.abs(p[:, :2]).max(1) >= lo) & (np.abs(p[:, :2]).max(1) < hi)]

    hits = np.concatenate([ring(0.5, 4.0, -1.0, 200), ring(4.0, 8.0, -1.5, 200), ring(8.0, 16.0, -3.0, 5)])
    heights, measured = ground_heights(hits, np.array([0.0, 0.0, 1.0]), radii, np.array([0.5, 0.7]))
    assert heights.tolist() == pytest.approx([-1.0, -1.5, -1.5])              # the outer ring takes its neighbour's
    assert measured["hits_per_layer"][2] < GROUND_MIN_HITS
    high, _ = ground_heights(ring(0.5, 4.0, 2.0, 200), np.array([0.0, 0.0, 1.0]), radii, np.array([0.5, 0.7]))
    assert (high < 0.5).all()                                                   # kept under the cameras
    none, _ = ground_heights(np.zeros((0, 3)), np.array([0.0, 0.0, 1.0]), radii, np.array([0.5]))
    assert none.size == 0
    record = Decisions()
    assert skybox_ground(0.25, 0.9, heights, record)
    assert not skybox_ground(0.09, 0.9, heights, record)                        # a sky
    assert not skybox_ground(0.25, 0.2, np.zeros(0), record)                    # haze: no ring has hits
    assert not skybox_ground(0.25, None, heights, record)                       # no far region
    kept, *left = record.items
    assert kept.kept and kept.measured["heights"] == pytest.approx([-1.0, -1.5, -1.5])
    assert [item.kept for item in left] == [False, False, False]
    assert "haze" in left[1].reason


def test_a_surface_from_fused_depths_says_how_much_haze_it_took_as_surface():
    """``choices.surface_source``: the fused surface's decision names the share of training pixels taken as a
    faint surface (``depth_fusion.faint_regions``), when fusion measured it."""
    from neuras_distill.pipeline.choices import Decisions, surface_source

    stats = dict(level_set_missed=0.036, fused_depths_missed=0.009, surface_from_depths=True)
    record = Decisions()
    surface_source({**stats, "fused_faint_pixels": 0.125}, record)
    surface_source(stats, record)
    with_haze, without = record.items
    assert with_haze.kept and with_haze.measured["fused_faint_pixels"] == pytest.approx(12.5)
    assert "12.5% of the training pixels" in with_haze.reason and "3.6%" in with_haze.reason
    assert "faint" not in without.reason and "fused_faint_pixels" not in without.measured
