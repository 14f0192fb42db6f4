"""The two SSIM implementations against each other and against scikit-image's.

- evaluation: ``neuras_distill.metrics.ssim`` (numpy/scipy, float64): 11x11 Gaussian window (sigma 1.5,
  truncated at 3.5 sigma), C1 = 0.01^2, C2 = 0.03^2, data range 1, the map averaged over the pixels whose
  window lies inside the image (5 px cropped per side) and the three channels: Wang et al. 2004.
- training: ``neuras_distill.neural.losses.ssim`` (torch, float32): the same formula and constants, 'valid'
  filtering, but by default a 7x7 window (the same sigma 1.5, renormalised over 7 taps), because it runs on
  16 px patches, where an 11x11 window would leave a 6x6 map. The training loss calls it with ``window=7``.

So, by design, the training SSIM with its 7x7 window is not the evaluation SSIM: a smaller window averages
over fewer pixels and the map covers 3 px more per side. With ``window=11`` it computes the evaluation's
SSIM, and then the only difference is float32 against float64.

Measured on the 48x64 images below (torch on the CPU, when this test was written):
    metrics.ssim vs skimage.metrics.structural_similarity (gaussian_weights, sigma 1.5, population
        covariance, data_range 1):                                       max |diff| 2.2e-16
    losses.ssim(window=11) vs metrics.ssim:                              max |diff| 4.8e-6 (float32)
    losses.ssim(window=7), as trained, vs metrics.ssim:                  max |diff| 0.0156 (the 1 px shift of
        an edge; 0.0085 for a noisy gradient), same ranking of the five distorted pairs.
The asserted tolerances are those measurements with a margin (EXACT, FLOAT32, TRAINING_WINDOW below).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from neuras_distill import metrics
from neuras_distill.neural import losses

skimage_metrics = pytest.importorskip("skimage.metrics")

EXACT = 1e-9            # metrics.ssim vs skimage: the same float64 computation
FLOAT32 = 2e-5          # losses.ssim(window=11) vs metrics.ssim: float32 against float64
TRAINING_WINDOW = 0.03  # losses.ssim(window=7) vs metrics.ssim: a 7x7 against an 11x11 window (by design)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """name -> (reference, distorted), (48, 64, 3) float64 in [0, 1]: a smooth gradient, noise and an edge."""
    rng = np.random.default_rng(0)
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w] / np.array([h - 1, w - 1], np.float64)[:, None, None]
    gradient = np.stack([x, y, 0.5 * (x + y)], axis=-1)
    noise = rng.uniform(0.0, 1.0, (h, w, 3))
    edge = np.where((x > 0.5)[..., None], np.array([0.9, 0.8, 0.2]), np.array([0.1, 0.2, 0.6]))
    return {
        "gradient + noise": (gradient, np.clip(gradient + rng.normal(0.0, 0.02, gradient.shape), 0.0, 1.0)),
        "gradient, contrast and brightness": (gradient, gradient * 0.9 + 0.05),
        "noise + noise": (noise, np.clip(noise + rng.normal(0.0, 0.1, noise.shape), 0.0, 1.0)),
        "edge blurred": (edge, gaussian_filter(edge, (1.0, 1.0, 0.0))),
        "edge shifted 1 px": (edge, np.roll(edge, 1, axis=1)),
    }


def _torch(image: np.ndarray) -> torch.Tensor:
    """(H, W, 3) numpy -> (1, 3, H, W) float32 tensor, the layout the training loss takes."""
    return torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1))[None]).float()


def _scores() -> dict[str, dict[str, float]]:
    out = {}
    for name, (ref, img) in _pairs().items():
        out[name] = {
            "eval": metrics.ssim(img, ref),
            "skimage": float(skimage_metrics.structural_similarity(
                img, ref, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0,
                channel_axis=-1)),
            "train11": float(losses.ssim(_torch(img), _torch(ref), window=11)),
            "train7": float(losses.ssim(_torch(img), _torch(ref), window=7)),
        }
    return out


@pytest.fixture(scope="module")
def scores():
    return _scores()


def test_the_pairs_are_not_trivial(scores):
    """Every distorted pair scores clearly below 1, and they spread: agreement is not agreement on 1.0."""
    values = [s["eval"] for s in scores.values()]
    assert max(values) < 0.995 and min(values) < 0.9, scores
    for image, _ in _pairs().values():
        assert metrics.ssim(image, image) == pytest.approx(1.0, abs=1e-12)
        assert float(losses.ssim(_torch(image), _torch(image), window=7)) == pytest.approx(1.0, abs=1e-6)


def test_evaluation_ssim_is_skimages(scores):
    for name, s in scores.items():
        assert abs(s["eval"] - s["skimage"]) <= EXACT, (name, s)


def test_training_ssim_with_the_evaluation_window_is_the_evaluation_ssim(scores):
    for name, s in scores.items():
        assert abs(s["train11"] - s["eval"]) <= FLOAT32, (name, s)


def test_training_ssim_as_trained_agrees_within_the_stated_tolerance(scores):
    diffs = {name: s["train7"] - s["eval"] for name, s in scores.items()}
    assert max(abs(d) for d in diffs.values()) <= TRAINING_WINDOW, diffs
    # the difference is the window's, not noise: larger than float32 rounding on some pair
    assert max(abs(d) for d in diffs.values()) > 10 * FLOAT32, diffs
    # and the training loss ranks the distortions as the evaluation does
    ranked = {kind: sorted(scores, key=lambda n: scores[n][kind]) for kind in ("train7", "eval")}
    assert ranked["train7"] == ranked["eval"], scores


def test_training_ssim_map_matches_the_evaluation_map_pixel_by_pixel():
    """Not only the means: with the 11x11 window the torch map equals the numpy map on the valid region."""
    ref, img = _pairs()["edge blurred"]
    r = 5
    c1, c2 = 0.01 ** 2, 0.03 ** 2

    def blur(x):
        return gaussian_filter(x, sigma=(1.5, 1.5, 0), truncate=3.5, mode="reflect")

    mu_a, mu_b = blur(img), blur(ref)
    s = ((2 * mu_a * mu_b + c1) * (2 * (blur(img * ref) - mu_a * mu_b) + c2)
         / ((mu_a ** 2 + mu_b ** 2 + c1) * (blur(img * img) - mu_a ** 2 + blur(ref * ref) - mu_b ** 2 + c2)))
    expected = s[r:-r, r:-r].mean(axis=-1)                                   # (H - 10, W - 10), channel mean
    assert expected.mean() == pytest.approx(metrics.ssim(img, ref), abs=1e-12)
    got = losses.ssim_map(_torch(img), _torch(ref), window=11)[0].double().numpy()
    assert got.shape == expected.shape
    np.testing.assert_allclose(got, expected, atol=FLOAT32 * 5)
