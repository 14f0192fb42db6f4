"""Extra training views around the capture's cameras (render/extra_views.py, choices.extra_views)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from neuras_distill.pipeline.choices import Decisions, extra_views as choose_extra_views
from neuras_distill.render.cameras import Cameras, look_at
from neuras_distill.render.extra_views import extra_views, inside_box, look_at_distances, path_views
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF


def _orbit(n: int = 12, radius: float = 4.0, size: int = 48) -> Cameras:
    """``n`` cameras on a horizontal circle of ``radius`` around the origin, looking at it (z up)."""
    poses = []
    for k in range(n):
        a = 2 * math.pi * k / n
        eye = torch.tensor([radius * math.cos(a), radius * math.sin(a), 0.3])
        poses.append(look_at(eye, torch.zeros(3), torch.tensor([0.0, 0.0, 1.0])))
    return Cameras(torch.stack(poses).float(), 40.0, 40.0, size / 2, size / 2, size, size)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0)))


def test_extra_views_turn_about_the_look_at_point_within_the_angle():
    cams = _orbit()
    distances = np.linalg.norm(cams.centers.double().numpy(), axis=1)      # each looks at the origin
    extra = extra_views(cams, distances, 60, 10.0, seed=3)
    assert len(extra) == 60 and (extra.width, extra.height) == (cams.width, cams.height)
    centres = extra.centers.double().numpy()
    np.testing.assert_allclose(np.linalg.norm(centres, axis=1), distances[0], rtol=1e-5)   # same distance
    forward = -extra.c2w[:, :3, 2].double().numpy()
    np.testing.assert_allclose(forward, -centres / np.linalg.norm(centres, axis=1, keepdims=True), atol=1e-5)
    src = cams.centers.double().numpy()
    turned = [min(_angle_deg(c, s) for s in src) for c in centres]
    assert max(turned) <= 10.0 + 1e-3 and max(turned) > 6.0             # the disc is covered, not exceeded
    again = extra_views(cams, distances, 60, 10.0, seed=3)
    assert torch.equal(again.c2w, extra.c2w)                             # seeded: a rerun adds the same views
    assert not torch.equal(extra_views(cams, distances, 60, 10.0, seed=4).c2w, extra.c2w)


def test_no_extra_views_without_a_look_at_point():
    cams = _orbit(4)
    assert extra_views(cams, np.full(4, np.inf), 5, 10.0) is None
    assert extra_views(cams, np.full(4, 2.0), 0, 10.0) is None
    reach = float(np.linalg.norm(cams.centers[1].double().numpy()))       # camera 1 looks at the origin
    only = extra_views(cams, np.array([np.inf, reach, np.inf, np.inf]), 3, 10.0)
    np.testing.assert_allclose(np.linalg.norm(only.centers.double().numpy(), axis=1), reach, rtol=1e-5)


def _drive(n: int = 10, spacing: float = 8.0, size: int = 32) -> Cameras:
    """``n`` cameras along the x axis, ``spacing`` apart, 1.6 up, looking ahead (+x), z up."""
    poses = [look_at(torch.tensor([k * spacing, 0.0, 1.6]), torch.tensor([k * spacing + 10.0, 0.0, 1.6]),
                     torch.tensor([0.0, 0.0, 1.0])) for k in range(n)]
    return Cameras(torch.stack(poses).float(), 20.0, 20.0, size / 2, size / 2, size, size)


def test_path_views_lie_between_neighbouring_cameras_turned_within_the_angle():
    cams = _drive()
    extra = path_views(cams, 40, 10.0, seed=1)
    assert len(extra) == 40 and (extra.width, extra.height) == (cams.width, cams.height)
    centres = extra.centers.double().numpy()
    np.testing.assert_allclose(centres[:, 1:], np.tile([0.0, 1.6], (40, 1)), atol=1e-5)     # on the path
    offset = np.mod(centres[:, 0], 8.0)
    assert np.all((offset >= 2.0 - 1e-4) & (offset <= 6.0 + 1e-4))     # 25-75% of the way to a neighbour
    assert 0.0 < centres[:, 0].min() and centres[:, 0].max() < 72.0
    forward = -extra.c2w[:, :3, 2].double().numpy()
    turned = [_angle_deg(f, np.array([1.0, 0.0, 0.0])) for f in forward]
    assert max(turned) <= 10.0 + 1e-3 and max(turned) > 6.0
    right = extra.c2w[:, :3, 0].double().numpy()
    assert np.abs(right[:, 2]).max() < 0.2                              # turned in yaw and pitch, no roll
    assert torch.equal(path_views(cams, 40, 10.0, seed=1).c2w, extra.c2w)
    assert path_views(cams, 0, 10.0) is None and path_views(cams[[0]], 5, 10.0) is None


def test_look_at_distances_find_the_surface():
    field = SphereSDF(radius=0.5)
    cams = _orbit(3, radius=3.0)
    d = look_at_distances(VolumeRenderer(field, 128), cams)
    assert np.all(np.abs(d - 2.55) < 0.1), d                             # the sphere's front at ~2.5 .. 2.6
    away = Cameras(look_at(torch.tensor([0.0, -3.0, 0.0]), torch.tensor([0.0, -6.0, 0.0]),
                           torch.tensor([0.0, 0.0, 1.0]))[None].float(), 40.0, 40.0, 24, 24, 48, 48)
    assert np.isinf(look_at_distances(VolumeRenderer(field, 128), away))[0]


def test_the_rule_adds_views_only_around_an_object_with_a_fringe_shell():
    record = Decisions()
    assert choose_extra_views("auto", np.zeros(10, bool), True, 40, 0.5, record) == 20
    assert choose_extra_views("auto", np.array([False, True]), True, 40, 0.5, record) == 0    # a drive
    assert choose_extra_views("auto", np.zeros(10, bool), False, 40, 0.5, record) == 0       # no shell
    assert choose_extra_views("on", np.array([True]), False, 40, 0.25, record) == 10
    assert choose_extra_views("off", np.zeros(3, bool), True, 40, 0.5, record) == 0
    kept = [d.kept for d in record.items]
    assert kept == [True, False, False, True, False]
    assert all(d.component == "extra training views" for d in record.items)
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert inside_box(_orbit(4, radius=4.0), box).tolist() == [False] * 4
    assert inside_box(_orbit(4, radius=0.5), box).tolist() == [True] * 4


@pytest.mark.gl
def test_a_sharp_surface_gets_no_extra_views(small_run):
    _, out = small_run
    report = json.loads((out / "report.json").read_text())
    decision = [d for d in report["decisions"] if d["component"] == "extra training views"]
    assert len(decision) == 1 and not decision[0]["kept"] and "no soft-fringe shell" in decision[0]["reason"]
    cams = json.loads((out / "cameras.json").read_text())
    assert len(cams["train"]["frames"]) + len(cams["test"]["frames"]) == 10      # the small run's own cameras


@pytest.mark.gl
@pytest.mark.slow
def test_a_fringed_ball_trains_on_extra_views_around_its_cameras(tmp_path, two_torch_threads):
    """The cameras stage of a soft-fringed density ball (the gradient ball): the extra views join the training
    cameras in ``cameras.json``, the held-out ones stay as they were."""
    import neuras_distill as nd
    from neuras_distill.pipeline.stages import split_cameras
    from neuras_distill.pipeline.stages.context import RunContext
    from neuras_distill.scenes.synthetic import make_scene

    field = make_scene("gradient-ball")
    cams = field.default_cameras(14, 160, 90)
    cfg = nd.load_config("fast", overrides={"cameras": {"test_every": 7}, "teacher": {"train_width": 160,
                                                                                        "num_steps": 96}})
    ctx = RunContext(field, cfg, tmp_path, None, lambda m: None, False)
    views = split_cameras(ctx, cams)
    decision = [d for d in ctx.decisions.items if d.component == "extra training views"]
    assert len(decision) == 1 and decision[0].kept, decision
    assert len(views.train) == 12 + 6 and len(views.test) == 2
    stored = json.loads((tmp_path / "cameras.json").read_text())
    assert len(stored["train"]["frames"]) == 18 and len(stored["test"]["frames"]) == 2
    base = cams.split(7)[0].centers.double().numpy()
    for c in views.train.centers[12:].double().numpy():              # near a training camera, not one of them
        nearest = min(_angle_deg(c, b) for b in base)
        assert 0.0 < nearest <= 10.0 + 1e-3
