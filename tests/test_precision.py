"""Mixed precision (``teacher.precision = "fp16"``): half hash-grid tables and MLPs, float32 compositing.

The teacher's image in fp16 must match fp32 within :data:`neuras_distill.precision.FP16_TEACHER_MIN_PSNR_DB` on
the Instant-NGP fixture (a real hash grid + tcnn MLPs); it must differ at all (the half path ran); the caller's
field keeps its float32 tables. CPU autocast runs float16 too (slowly), so this is checked here; the GPU speed
is a benchmark figure (benchmarks/device_runs.py --precision fp16).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuras_distill.components.tcnn import HashGridEncoding
from neuras_distill.device_field import on_device
from neuras_distill.errors import BadInputError
from neuras_distill.precision import FP16_TEACHER_MIN_PSNR_DB, half_tables
from neuras_distill.registry import load_field
from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.analytic import orbit_framing

BALL = Path(__file__).parent / "data" / "ngp" / "ball.ingp"


def _grids(field) -> list[HashGridEncoding]:
    from neuras_distill.precision import _modules

    return [m for m in _modules(field, set()) if isinstance(m, HashGridEncoding)]


@pytest.mark.slow
def test_the_fp16_teacher_matches_fp32_within_the_stated_tolerance():
    field = load_field(BALL)
    cams = orbit_framing(field.aabb, 2, 64, 64)
    full = VolumeRenderer(field, num_steps=128, occupancy=None).render(cams, 0)
    half_field = on_device(field, "cpu", "fp16")
    assert half_field.half_tables >= 1
    half = VolumeRenderer(half_field, num_steps=128, occupancy=None).render(cams, 0)
    assert half["rgb"].dtype == np.float32
    mse = float(np.mean((half["rgb"] - full["rgb"]) ** 2))
    psnr = 10 * np.log10(1.0 / max(mse, 1e-20))
    assert psnr >= FP16_TEACHER_MIN_PSNR_DB, psnr
    assert mse > 0.0, "fp16 gave the fp32 image bit for bit: the half path did not run"
    assert np.abs(half["opacity"] - full["opacity"]).max() < 0.02
    # the caller's field is untouched: its tables stay float32
    assert all(g.params.dtype == torch.float32 for g in _grids(field))


@pytest.mark.slow
def test_half_tables_converts_every_hash_grid_and_nerfstudios_table():
    from adapters.nerfstudio.adapter import NerfstudioAdapter

    field = load_field(BALL)
    n = len(_grids(field))
    assert n >= 1 and half_tables(field) == n
    assert all(g.params.dtype == torch.float16 for g in _grids(field))
    ns = NerfstudioAdapter().load(Path(__file__).parent / "data" / "nerfstudio" / "bunny")
    assert half_tables(ns) == 1 and ns.network.base[0].hash_table.dtype == torch.float16


def test_a_precision_that_is_not_one_is_refused():
    from neuras_distill.config import load_config

    with pytest.raises(BadInputError, match="precision 'fp8' is not one of fp32, fp16"):
        load_config(overrides={"teacher": {"precision": "fp8"}})
