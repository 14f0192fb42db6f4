"""End to end with skyboxes: a sphere under a sky with a gradient and a sun, placed kilometres from the world
origin. The pipeline must decide to build skyboxes, train and bake them, play them in OpenGL as trained, and
show what they are worth (the ablation without them)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import neuras_distill as nd
from neuras_distill.bake.bundle import load_bundle
from neuras_distill.errors import BadInputError
from neuras_distill.scenes.analytic import SphereSDF

pytestmark = [pytest.mark.gl]

FAR = (3000.0, -2000.0, 50.0)


class SkySphere(SphereSDF):
    """A sphere whose background changes with direction everywhere (the orbit looks down on it, so the sky
    alone would hardly show): colour 0.5 + 0.35 d, a warm band along the horizon, and a sun."""

    def background(self, d: torch.Tensor) -> torch.Tensor:
        base = 0.5 + 0.35 * d
        band = 0.3 * torch.exp(-30.0 * d[:, 2:3] ** 2) * torch.tensor([1.0, 0.6, 0.2])
        sun = torch.exp(-40.0 * (1.0 - d @ torch.tensor([0.6, 0.0, 0.8])))[:, None]
        return (base + band + sun).clamp(0.0, 1.0)


@pytest.fixture(scope="module")
def sky_run(tmp_path_factory, torch_threads):
    out = tmp_path_factory.mktemp("sky") / "run"
    field = SkySphere(center=FAR, radius=0.5)
    cams = field.default_cameras(10, 96, 64)
    cfg = nd.load_config("fast", overrides={"train": {"steps": 300}, "eval": {"width": 128, "fps_frames": 5},
                                            "texture": {"resolution": 128, "num_codes": 128},
                                            "skybox": {"layers": 2, "resolution": 16, "num_codes": 64}})
    with torch_threads(2):
        result = nd.distill(field, cams, cfg, out=out, progress=False, log=lambda m: None)
    return result, out


def test_skyboxes_are_built_and_reported(sky_run):
    result, out = sky_run
    rep = json.loads((out / "report.json").read_text())
    assert rep["skybox"]["used"] and "miss the mesh" in rep["skybox"]["reason"]
    assert all(item["component"] != "skyboxes" for item in rep["left_out"])
    assert len(rep["skybox"]["half_sizes"]) == 2
    assert np.allclose(rep["skybox"]["center"], FAR) and np.allclose(rep["origin"], FAR)
    bundle = load_bundle(out / "bundle")
    assert bundle.has_skybox and np.allclose(bundle.origin, FAR)
    assert np.abs(bundle.mesh.vertices).max() < 1.0          # stored relative to the scene centre


def test_skyboxes_play_as_trained_and_are_worth_it(sky_run):
    result, _ = sky_run
    rep = result.report
    assert rep["parity_psnr"] >= 40.0
    assert rep["psnr"] > 27.0, rep["psnr_per_view"]
    assert rep["ablation"]["drop_db"] >= 2.0, rep["ablation"]


@pytest.mark.slow
def test_skybox_that_does_not_enclose_the_cameras_is_refused(tmp_path):
    field = SkySphere(center=(0.0, 0.0, 0.0), radius=0.5)
    cams = field.default_cameras(6, 48, 32)
    cfg = nd.load_config("fast", overrides={"skybox": {"near": 0.5, "far": 10.0}, "train": {"steps": 5}})
    with pytest.raises(BadInputError, match="does not enclose every camera"):
        nd.distill(field, cams, cfg, out=tmp_path / "r", progress=False, log=lambda m: None)
    assert not (tmp_path / "r").exists()
    with pytest.raises(BadInputError, match="must nest"):
        nd.load_config(overrides={"skybox": {"near": 50.0, "far": 10.0}})
