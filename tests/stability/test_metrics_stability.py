"""Evaluation metrics on broken images: a NaN or Inf pixel must never give a finite, good-looking PSNR or SSIM."""

from __future__ import annotations

import math

import numpy as np
import pytest

from neuras_distill.metrics import psnr, region_psnr, ssim

S = pytest.mark.stability


def _pair():
    rng = np.random.default_rng(0)
    ref = rng.random((32, 32, 3))
    return ref.copy(), ref


@S(case="NaN pixel: PSNR and SSIM", family="metrics",
   reference="NaN (was PSNR 100 dB, the best score, before the fix)", tolerance="exact: NaN")
@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_nonfinite_pixel(bad):
    img, ref = _pair()
    img[5, 7, 1] = bad
    assert math.isnan(psnr(img, ref)) and math.isnan(ssim(img, ref))
    assert math.isnan(psnr(ref, img)) and math.isnan(ssim(ref, img))


@S(case="NaN pixel inside / outside a region mask", family="metrics",
   reference="NaN inside the mask -> NaN; outside -> the finite score of the masked pixels", tolerance="exact")
def test_region_mask():
    img, ref = _pair()
    img[0, 0, 0] = np.nan
    mask = np.zeros((32, 32), bool)
    mask[0, 0] = True
    assert math.isnan(region_psnr(img, ref, mask))
    assert region_psnr(img, ref, ~mask) == 100.0


@S(case="identical and opposite images", family="metrics",
   reference="identical: 100 dB (MSE clamped at 1e-10), SSIM 1; black vs white: 0 dB", tolerance="exact / 1e-12")
def test_limits():
    img, ref = _pair()
    assert psnr(img, ref) == 100.0 and ssim(img, ref) == pytest.approx(1.0, abs=1e-12)
    assert psnr(np.zeros((8, 8, 3)), np.ones((8, 8, 3))) == pytest.approx(0.0, abs=1e-12)
