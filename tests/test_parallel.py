"""--nproc: worker processes share the teacher's volume rendering (neuras_distill.pipeline.parallel, torch.distributed gloo)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.pipeline.parallel import RenderPool, check_nproc, max_processes
from neuras_distill.pipeline.evaluate import render_field_views
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import SphereSDF


class DiesInWorkers(SphereSDF):
    """A sphere whose evaluation kills any process but the one that made it (a crashing worker)."""

    def __init__(self):
        super().__init__(radius=0.5)
        self.parent = os.getpid()

    def geometry(self, x):
        if os.getpid() != self.parent:
            os._exit(3)
        return super().geometry(x)


class FailsToArrive(SphereSDF):
    """A sphere that cannot be unpickled in a worker (a worker that dies before the group forms)."""

    def __setstate__(self, state):
        raise RuntimeError("this field refuses to be unpickled")


class HoldsALocalFunction(SphereSDF):
    def __init__(self):
        super().__init__(radius=0.5)
        self.shade = lambda x: x       # pickle cannot send a lambda to a worker


def test_nproc_is_checked_with_one_line():
    assert check_nproc("2") == 2 and check_nproc(1) == 1
    with pytest.raises(BadInputError, match="at least 1"):
        check_nproc(0)
    with pytest.raises(BadInputError, match="whole number"):
        check_nproc("two")
    with pytest.raises(BadInputError, match=f"use --nproc {max_processes()} or fewer"):
        check_nproc(max_processes() + 1)


def test_two_processes_render_what_one_renders():
    field = SphereSDF(radius=0.5)
    cams = field.default_cameras(5, 40, 32)
    renderer = VolumeRenderer(field, num_steps=64)
    one = render_field_views(renderer, cams, depths=True)
    with RenderPool(field, 2, timeout_s=120) as pool:
        two = pool.render_views(renderer, cams, depths=True)
        again = pool.render_views(renderer, cams[:3], depths=False)   # the pool serves more than one request
    assert len(two.images) == 5 and len(again.images) == 3 and again.surface_depths == []
    for a, b in zip(one.images + one.opacities + one.surface_depths + one.fringe_depths,
                    two.images + two.opacities + two.surface_depths + two.fringe_depths):
        assert a.shape == b.shape and float(np.abs(a - b).max()) < 1e-5
    assert float(np.abs(one.images[0] - again.images[0]).max()) < 1e-5
    assert one.images[0].std() > 0.05           # not a blank frame: the sphere is in view


def test_two_processes_render_a_scene_far_from_the_origin_as_one_does():
    """Far from the origin the renderer marches in a local frame; the workers rebuild it from the world field."""
    from neuras_distill.stability.extreme import make_extreme

    field = make_extreme("geo-sphere-1e5")
    cams = field.default_cameras(3, 24, 24)
    renderer = VolumeRenderer(field, num_steps=64)
    assert renderer.frame is not None
    one = render_field_views(renderer, cams)
    with RenderPool(field, 2, timeout_s=120) as pool:
        two = pool.render_views(renderer, cams)
    for a, b in zip(one.images, two.images):
        assert float(np.abs(a - b).max()) < 1e-5
    assert one.images[0].std() > 0.05


def test_a_worker_that_dies_ends_the_render_with_one_line():
    field = DiesInWorkers()
    cams = field.default_cameras(4, 16, 16)
    renderer = VolumeRenderer(field, num_steps=16, occupancy=None)
    pool = RenderPool(field, 2, timeout_s=60)
    with pytest.raises(BadInputError, match=r"--nproc 2: a worker process failed.*run with --nproc 1"):
        pool.render_views(renderer, cams)
    pool.close()
    assert not torch.distributed.is_initialized()


def test_a_worker_that_exits_while_starting_is_noticed_at_once():
    import time

    t0 = time.perf_counter()
    with pytest.raises(BadInputError, match=r"a worker process exited while starting.*--nproc 1"):
        RenderPool(FailsToArrive(radius=0.5), 2, timeout_s=600)
    assert time.perf_counter() - t0 < 120          # not the 600 s group timeout


def test_a_field_that_cannot_be_sent_is_refused():
    with pytest.raises(BadInputError, match=r"cannot be sent to worker processes.*--nproc 1"):
        RenderPool(HoldsALocalFunction(), 2, timeout_s=30)


@pytest.mark.gl
@pytest.mark.slow
def test_cli_nproc_runs_and_refuses(tmp_path, capsys):
    from neuras_distill.cli import main

    bad = tmp_path / "bad"
    assert main(["from-synthetic", "sphere", "--out", str(bad), "--nproc", "0", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--nproc must be at least 1" in err[0] and not bad.exists()

    out = tmp_path / "run"
    code = main(["from-synthetic", "sphere", "--preset", "fast", "--steps", "200", "--eval-width", "96",
                 "--out", str(out), "--nproc", "2", "--device", "cpu", "--quiet"])
    assert code == 0
    rep = json.loads((out / "report.json").read_text())
    assert rep["processes"] == 2 and rep["psnr"] > 28.0, (rep["processes"], rep["psnr"])


def _trained_together(nproc: int, coarse_factor: int = 1, **kwargs):
    """A small texture model trained on a synthetic G-buffer by ``nproc`` processes (1: plain ``fit``)."""
    from test_neural import synthetic_gbuffer

    from neuras_distill.neural.model import NeuralTextureModel
    from neuras_distill.config import TrainConfig
    from neuras_distill.neural.train import fit
    from neuras_distill.neural.train_batches import TrainingPixels

    data = synthetic_gbuffer(n=3, res=24)
    torch.manual_seed(0)
    model = NeuralTextureModel(32, 32, feature_dim=8, num_codes=32, hidden=16, use_vq=True,
                               coarse_factor=coarse_factor)
    start = {k: v.clone() for k, v in model.state_dict().items()}
    args = dict(steps=30, config=TrainConfig(batch_patches=6, patch=8, **kwargs), progress=False)
    if nproc == 1:
        log = fit(model, TrainingPixels(*data), num_threads=1, **args)
    else:
        with RenderPool(SphereSDF(radius=0.5), nproc, timeout_s=120) as pool:
            log = pool.fit(model, TrainingPixels(*data), **args)
    return model, log, start


@pytest.mark.slow
def test_two_processes_train_the_model_one_process_trains():
    """Data-parallel fit: each rank computes half of every batch, gradients (the atlas's sparse rows included)
    are summed, so 2 gloo processes end with 1 process's model up to the order of float additions (stated
    tolerance 1e-4 after 30 Adam steps; measured ~1e-7)."""
    one, log1, start = _trained_together(1)
    two, log2, _ = _trained_together(2)
    assert (log1.processes, log2.processes) == (1, 2) and log1.steps == log2.steps == 30
    assert log2.pixels_per_second_per_process > 0
    a, b = one.state_dict(), two.state_dict()
    assert a.keys() == b.keys()
    for k in a:
        if a[k].dtype == torch.bool:
            assert torch.equal(a[k], b[k]), k               # touched texels: the union of both ranks'
        elif a[k].is_floating_point():
            assert float((a[k] - b[k]).abs().max()) < 1e-4, (k, float((a[k] - b[k]).abs().max()))
    moved = float((a["texture.data"] - start["texture.data"]).abs().max())
    assert moved > 0.05, moved                               # training did change the atlas
    assert abs(log1.entries[-1]["loss"] - log2.entries[-1]["loss"]) < 1e-4   # the logged loss is the whole batch's


@pytest.mark.slow
def test_two_processes_train_the_coarse_level_one_process_trains():
    """With the atlas's coarse level (dense gradients, summed by the all-reduce) 2 processes give 1 process's
    pictures. Not its parameters to 1e-4: a coarse texel sums the gradients of 64 fine ones, and where they
    nearly cancel the order of the additions picks the sign that Adam's first steps move it a whole learning
    rate by (measured: atlas 3e-3 apart after 30 steps, against 3e-7 without the level)."""
    from test_neural import _psnr, synthetic_gbuffer

    one, log1, _ = _trained_together(1, coarse_factor=8)
    two, log2, _ = _trained_together(2, coarse_factor=8)
    assert one.texture.coarse.shape == (4, 4, 8) and log1.steps == log2.steps == 30
    assert float(one.texture.coarse.detach().abs().max()) == 0.0     # folded into the atlas after training
    data = synthetic_gbuffer(n=3, res=24)
    uv, cov, dirs, _ = data
    a = one.render_gbuffer(uv[0], cov[0], dirs[0], np.zeros(3))
    b = two.render_gbuffer(uv[0], cov[0], dirs[0], np.zeros(3))
    assert float(np.abs(a - b).max()) < 1e-2, float(np.abs(a - b).max())
    assert abs(_psnr(one, *data) - _psnr(two, *data)) < 0.05


@pytest.mark.slow
def test_two_processes_under_quantized_training_stay_close():
    """Quantized from mid-run (vq_warmup 0.5), dead codes restart from each rank's own samples, so the models
    are no longer equal to one process's; their PSNR on the training data stays within 1 dB of it."""
    from test_neural import _psnr, synthetic_gbuffer

    data = synthetic_gbuffer(n=3, res=24)
    one, log1, _ = _trained_together(1, vq_warmup=0.5)
    two, log2, _ = _trained_together(2, vq_warmup=0.5)
    assert log1.vq_start_step == log2.vq_start_step == 15
    assert abs(_psnr(one, *data) - _psnr(two, *data)) < 1.0, (_psnr(one, *data), _psnr(two, *data))
