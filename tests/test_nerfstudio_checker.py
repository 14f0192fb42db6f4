"""A second nerfacto run made by nerfstudio's own trainer, with what the first lacks: a high-contrast checker
ground that runs to the horizon, 16 hash levels of 2^14 entries, 1000 steps (partly trained).

The fixture ``tests/data/nerfstudio/checker360`` was made by ``scripts/make_nerfstudio_unbounded_fixture.py --ground
checker`` (nerfstudio 1.1.5; its checkpoint's floats stored in half precision, its ``reference_renders.npz``
nerfstudio's renders of six held-out views made from those values, with the seconds each took).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuras_distill.config import TeacherConfig
from neuras_distill.registry import load_field
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.volume import VolumeRenderer

RUN = Path(__file__).parent / "data" / "nerfstudio" / "checker360"


def _psnr(a, b):
    return -10.0 * float(np.log10(max(float(((a - b) ** 2).mean()), 1e-12)))


def test_the_fixture_keeps_nerfstudios_renders_and_their_times():
    ref = np.load(RUN / "reference_renders.npz")
    assert ref["rgb"].shape == (6, 120, 160, 3) and ref["rgb"].dtype == np.uint8
    assert ref["seconds"].shape == (6,) and bool((ref["seconds"] > 0).all()) and int(ref["threads"]) >= 1
    ckpt = next((RUN / "nerfstudio_models").glob("step-*.ckpt"))
    assert ckpt.stat().st_size < 2 * 1024 * 1024


@pytest.mark.slow
def test_the_half_precision_checkpoint_loads_and_the_teacher_draws_nerfstudios_picture():
    """Two held-out views, every third pixel: the ground's high-contrast tiles to the horizon (the far region
    sampled at the teacher's default far steps) against nerfstudio's own renders."""
    field = load_field(RUN / "config.yml")
    assert field.unbounded and field.far_region is not None
    ref = np.load(RUN / "reference_renders.npz")
    f = float(ref["focal"])
    cams = Cameras(torch.from_numpy(ref["c2w"]).float(), f, f, 80.0, 60.0, 160, 120)
    teacher = TeacherConfig()
    renderer = VolumeRenderer(field, num_steps=teacher.num_steps, far_steps=teacher.far_steps,
                              occupancy_resolution=64)
    img, want = [], []
    for i in (1, 4):
        origins, dirs = cams.rays(i)
        img.append(renderer.render_rays(origins[::3, ::3].reshape(-1, 3), dirs[::3, ::3].reshape(-1, 3))["rgb"].numpy())
        want.append(ref["rgb"][i][::3, ::3].reshape(-1, 3).astype(np.float32) / 255.0)
    score = _psnr(np.concatenate(img), np.concatenate(want))
    print(f"teacher vs nerfstudio: {score:.2f} dB")
    assert score >= 31.0, score
