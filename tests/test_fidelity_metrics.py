"""Fidelity metrics: FLIP, the silhouette band / interior regions from the field's opacity, hole fraction,
region PSNR, the worst-FLIP crop windows and the side-by-side panels."""

from __future__ import annotations

import numpy as np
import pytest

from neuras_distill import metrics
from neuras_distill.pipeline import evaluate
from neuras_distill.pipeline.report import flip_colors


def _disc(size: int = 81, radius: int = 25) -> tuple[np.ndarray, int]:
    """(size, size) float32 opacity: 1 on a hard disc of ``radius`` around the centre pixel, 0 elsewhere."""
    c = size // 2
    y, x = np.mgrid[:size, :size]
    return (((x - c) ** 2 + (y - c) ** 2) <= radius ** 2).astype(np.float32), c


def _brute_band(inside: np.ndarray, band: int) -> np.ndarray:
    """Pixels whose nearest pixel of the other class is at most ``band`` away (brute force)."""
    pts_in, pts_out = np.argwhere(inside), np.argwhere(~inside)
    out = np.zeros_like(inside)
    for p in np.argwhere(np.ones_like(inside)):
        other = pts_out if inside[tuple(p)] else pts_in
        out[tuple(p)] = np.sqrt(((other - p) ** 2).sum(axis=1)).min() <= band
    return out


def test_flip_identical_is_zero_and_different_is_large():
    rng = np.random.default_rng(0)
    img = rng.random((48, 64, 3)).astype(np.float32)
    mean, error_map = metrics.flip(img, img)
    assert mean == 0.0 and error_map.shape == (48, 64) and error_map.dtype == np.float32
    assert np.all(error_map == 0.0)
    other = rng.random((48, 64, 3)).astype(np.float32)
    mean, error_map = metrics.flip(other, img)
    assert mean > 0.1
    assert mean == pytest.approx(float(error_map.mean()), rel=1e-4)
    assert 0.0 <= error_map.min() and error_map.max() <= 1.0
    # a small change scores lower than a large one
    slight = np.clip(img + 0.02, 0, 1)
    assert 0.0 < metrics.flip(slight, img)[0] < mean


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("which", ["image", "reference"])
def test_flip_non_finite_pixel_gives_nan(bad, which):
    img = np.full((16, 16, 3), 0.5, np.float32)
    broken = img.copy()
    broken[3, 4, 1] = bad
    a, b = (broken, img) if which == "image" else (img, broken)
    mean, error_map = metrics.flip(a, b)
    assert np.isnan(mean)
    assert np.isnan(error_map[3, 4]) and np.isfinite(np.delete(error_map.ravel(), 3 * 16 + 4)).all()


def test_flip_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="H, W, 3"):
        metrics.flip(np.zeros((8, 8, 3)), np.zeros((8, 9, 3)))


def test_band_width_default():
    assert metrics.band_width(1080, 1920) == 9
    assert metrics.band_width(128, 128) == 2       # 0.72 rounds to 1, raised to the minimum 2
    assert metrics.band_width(2160, 3840) == 18


def test_silhouette_band_and_interior_on_a_disc():
    opacity, c = _disc()
    r, band = 25, 3
    mask = metrics.silhouette_band(opacity, band)
    np.testing.assert_array_equal(mask, _brute_band(opacity > 0.5, band))
    # along the row through the centre: 3 pixels inside and 3 outside the boundary on each side
    row = mask[c]
    assert row[c + r - 2: c + r + 4].all() and not row[c + r - 3] and not row[c + r + 4]
    assert row[c - r - 3: c - r + 3].all() and not row[c - r - 4] and not row[c - r + 3]
    assert row.sum() == 12
    interior = metrics.interior_mask(opacity, mask)
    assert not (interior & mask).any()
    np.testing.assert_array_equal(interior, (opacity > 0.98) & ~mask)
    assert interior[c, c] and not interior[c, c + r - 2] and not interior[0, 0]
    # default band width on this 81x81 image: max(2, round(0.004 * 114.6)) = 2
    assert metrics.silhouette_band(opacity)[c].sum() == 8


def test_soft_fringe_is_band_wherever_it_is():
    opacity, c = _disc()
    opacity[2:5, 2:5] = 0.3            # translucent, below the mask level, far from the disc
    opacity[c - 1: c + 2, c - 1: c + 2] = 0.9    # a soft dip in the middle of the disc
    mask = metrics.silhouette_band(opacity, band=3)
    assert mask[2:5, 2:5].all() and not mask[10, 10]
    assert mask[c - 1: c + 2, c - 1: c + 2].all()
    assert not metrics.interior_mask(opacity, mask)[c, c]
    assert not metrics.silhouette_band(np.full((20, 20), 1.0, np.float32)).any()   # no boundary, no fringe
    assert metrics.silhouette_band(np.full((20, 20), 0.5, np.float32)).all()       # all fringe


def test_hole_fraction_matches_a_hand_count():
    opacity = np.zeros((10, 10), np.float32)
    opacity[:, :5] = 1.0        # opaque left half
    opacity[:, 5] = 0.4         # translucent column: below the mask level, never a hole
    coverage = np.ones((10, 10), bool)
    coverage[2:5, 0:5] = False  # 15 uncovered opaque pixels: holes
    coverage[:, 5:] = False     # nothing drawn over the transparent part: no holes
    assert metrics.hole_mask(opacity, coverage).sum() == 15
    assert metrics.hole_fraction(opacity, coverage) == pytest.approx(15 / 100)
    assert metrics.hole_fraction(opacity, np.ones((10, 10), bool)) == 0.0
    with pytest.raises(ValueError, match="differ"):
        metrics.hole_fraction(opacity, coverage[:5])


def test_region_psnr_separates_band_from_interior():
    opacity, c = _disc(size=96, radius=30)
    rng = np.random.default_rng(1)
    field = rng.uniform(0.2, 0.8, (96, 96, 3)).astype(np.float32)
    band = metrics.silhouette_band(opacity, 3)
    bundle = field.copy()
    bundle[band] += 0.1                         # wrong only on the silhouette band
    coverage = opacity > 0.5
    coverage[c, c] = False                      # one hole
    entry, flip_map = evaluate.view_fidelity(bundle, field, opacity, coverage, band=3)
    assert entry["psnr_interior"] == metrics.MAX_PSNR
    assert entry["psnr_silhouette"] == pytest.approx(20.0, abs=1e-3)
    assert metrics.psnr(bundle, field) > entry["psnr_silhouette"]
    assert entry["hole_fraction"] == pytest.approx(1 / 96 ** 2)
    assert entry["flip"] > 0 and flip_map.shape == (96, 96)
    # FLIP lives on the band: the band crop window sees more error than the interior one
    assert entry["crops"]["a"]["flip"] > entry["crops"]["b"]["flip"]
    assert entry["crops"]["a"]["box"] == [0, 0, 96, 96]          # smaller than 256: the whole image


def test_smooth_region_is_where_the_field_is_flat_and_scores_mottling_there():
    # a flat wall (left) next to a fine checker (right): the wall is smooth, the checker is not
    field = np.full((64, 64, 3), 0.5, np.float32)
    field[:, 32:] = np.where((np.add.outer(np.arange(64), np.arange(32)) % 2)[..., None] == 1, 0.2, 0.8)
    smooth = metrics.smooth_mask(field)
    assert smooth[:, :29].all() and not smooth[:, 32:].any()   # within 2 px of the checker the window sees it
    # luma std just below / above the threshold: a ramp whose 5x5 std is known (uniform over 5 values)
    ramp = np.broadcast_to((np.arange(64) % 5 * 0.006)[None, :, None], (64, 64, 3)).astype(np.float64)
    assert metrics.smooth_mask(ramp, threshold=0.0086)[10:54, 10:54].all()       # std = 0.006 * sqrt(2) = 0.00849
    assert not metrics.smooth_mask(ramp, threshold=0.0084)[10:54, 10:54].any()
    # mottling on the wall: +-0.02 blotches lower the smooth score and leave the checker's pixels alone
    bundle = field.copy()
    blotches = (np.arange(64)[:, None] // 8 + np.arange(32)[None, :] // 8) % 2 == 1
    bundle[:, :32] += np.where(blotches, 0.02, -0.02)[..., None]
    entry, _ = evaluate.view_fidelity(bundle, field, np.ones((64, 64), np.float32), np.ones((64, 64), bool))
    assert entry["psnr_smooth"] == pytest.approx(-10 * np.log10(0.02 ** 2), abs=1e-3)     # 33.98 dB
    assert entry["smooth_fraction"] == pytest.approx(smooth.mean())
    with pytest.raises(ValueError, match="H, W, 3"):
        metrics.smooth_mask(field[..., 0])


def test_empty_regions_give_none_not_a_perfect_score():
    field = np.full((32, 32, 3), 0.5, np.float32)
    empty = np.zeros((32, 32), np.float32)
    entry, _ = evaluate.view_fidelity(field + 0.1, field, empty, np.zeros((32, 32), bool))
    assert entry["psnr_interior"] is None and entry["psnr_silhouette"] is None
    assert entry["crops"] == {} and entry["hole_fraction"] == 0.0
    out, maps = evaluate.fidelity([field + 0.1, field], [field, field], [empty, empty + 1.0],
                                  [np.zeros((32, 32), bool)] * 2)
    assert out["psnr_interior_per_view"][0] is None and out["psnr_interior"] == metrics.MAX_PSNR
    assert out["hole_fraction_per_view"] == [0.0, 1.0] and out["hole_fraction"] == 0.5
    assert out["flip"] == pytest.approx(0.5 * out["flip_per_view"][0]) and len(maps) == 2


def test_worst_window_finds_the_hot_region_and_clamps():
    err = np.zeros((600, 800), np.float32)
    region = np.zeros((600, 800), bool)
    region[:, :400] = True
    err[100:140, 50:90] = 0.8            # hot, inside the region
    err[300:340, 600:640] = 1.0          # hotter, outside the region: ignored
    x0, y0, w, h = evaluate.worst_window(err, region)
    assert (w, h) == (256, 256)
    assert x0 <= 70 - 16 and x0 + 256 >= 70 + 16 and y0 <= 120 - 16 and y0 + 256 >= 120 + 16
    assert x0 == 0                       # a centre near the left edge is clamped into the image
    err2 = np.zeros((600, 800), np.float32)
    err2[580:600, 780:800] = 1.0
    assert evaluate.worst_window(err2, np.ones((600, 800), bool)) == [800 - 256, 600 - 256, 256, 256]
    assert evaluate.worst_window(err, np.zeros((600, 800), bool)) is None


def test_side_by_side_panels_and_flip_colours():
    f = np.zeros((20, 30, 3), np.float32)
    assert evaluate.side_by_side(f, f).shape == (20, 3 * 30 + 2 * 4, 3)
    flip_map = np.zeros((20, 30), np.float32)
    flip_map[0, 0] = np.nan
    flip_map[1, 1] = 1.0
    panel = flip_colors(flip_map)
    assert panel.shape == (20, 30, 3) and panel.dtype == np.float32
    np.testing.assert_allclose(panel[0, 0], [0, 1, 1])           # NaN is cyan
    assert panel[5, 5].max() < 0.05 and panel[1, 1].min() > 0.6  # magma: 0 black, 1 pale yellow
    row = evaluate.side_by_side(f, f, flip_panel=panel)
    assert row.shape == (20, 4 * 30 + 3 * 4, 3) and row.dtype == np.uint8
    crop = evaluate.crop_strip(f, f, panel, [1, 1, 10, 8])        # x0 1, y0 1: starts at the 1.0 pixel
    assert crop.shape == (8, 3 * 10 + 2 * 4, 3)
    np.testing.assert_array_equal(crop[0, 2 * 14], (panel[1, 1] * 255 + 0.5).astype(np.uint8))
    assert crop[0, 2 * 14].min() > 150 and crop[0, 0].max() == 0  # FLIP panel unscaled, field panel black


def test_the_texel_footprint_benchmark_reads_gl_level_of_detail():
    """benchmarks/texel_footprint.py (what a feature pyramid could buy): lambda = log2(texels per pixel along
    the longer screen axis), from same-face neighbours only."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "texel_footprint.py"
    spec = importlib.util.spec_from_file_location("texel_footprint", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    h, w = 8, 12
    yy, xx = np.meshgrid(np.arange(h, dtype=np.float32), np.arange(w, dtype=np.float32), indexing="ij")
    uv = np.stack([xx / 64.0, yy / 16.0], -1)            # per pixel: 1/64 of u, 1/16 of v
    face = np.zeros((h, w), np.int64)
    face[:, 6:] = 1                                      # two faces side by side
    face[0, 0] = -1                                      # an uncovered pixel
    lod = bench.level_of_detail(uv, face, height=64, width=256)     # 4 texels per pixel in both directions
    assert np.isnan(lod[0, 0])
    finite = np.isfinite(lod)
    assert finite.sum() >= h * w - 3
    np.testing.assert_allclose(lod[finite], 2.0, atol=1e-5)
    uv_across = uv.copy()
    uv_across[:, 6:, 0] += 0.5                           # a chart seam between the faces: not a uv step
    np.testing.assert_allclose(bench.level_of_detail(uv_across, face, 64, 256)[finite], 2.0, atol=1e-5)


def test_scores_split_inside_and_outside_the_foreground_box():
    """Inside the box = field opacity >= 0.5 there; an error only outside leaves the inside exact."""
    opacity = np.zeros((32, 32), np.float32)
    opacity[8:24, 8:24] = 1.0
    rng = np.random.default_rng(2)
    field = rng.uniform(0.2, 0.8, (32, 32, 3)).astype(np.float32)
    bundle = field.copy()
    bundle[opacity < 0.5] += 0.05                 # wrong only beyond the box (the far region)
    entry, flip_map = evaluate.view_fidelity(bundle, field, opacity, opacity > 0.5)
    assert entry["psnr_inside_box"] == metrics.MAX_PSNR
    assert entry["psnr_outside_box"] == pytest.approx(-10 * np.log10(0.05 ** 2), abs=1e-3)
    assert entry["flip_inside_box"] < entry["flip_outside_box"]
    assert entry["flip_inside_box"] == pytest.approx(float(flip_map[opacity >= 0.5].mean()))
    summary, _ = evaluate.fidelity([bundle], [field], [opacity], [opacity > 0.5])
    assert summary["psnr_outside_box"] == entry["psnr_outside_box"] and summary["psnr_inside_box_per_view"]


def test_error_vs_runtime_reuses_the_held_out_render_at_the_teacher_steps():
    """The curve's point at the teacher's step count is the held-out render already made (its image and time);
    the other step counts and the reference are rendered, each once."""
    rendered = []

    class Field:
        def __init__(self, steps):
            self.steps = steps

        def render(self, cam, index):
            rendered.append(self.steps)
            return {"rgb": np.full((4, 6, 3), 0.5 + 0.5 / self.steps, np.float32)}

    class Bundle:
        def time_frames(self, cam, warmup, frames):
            return {"median_ms": 2.0}

        def render(self, cam, index):
            return np.full((4, 6, 3), 0.5, np.float32)

    held_out = np.full((4, 6, 3), 0.25, np.float32)
    points = evaluate.error_vs_runtime(Field, [object()], 512, [32, 64], 256, Bundle(), main_render=(held_out, 7.5))
    assert sorted(rendered) == [32, 64, 512]
    main = next(p for p in points if p.get("steps") == 256)
    assert main["seconds_per_frame"] == 7.5
    assert main["psnr"] == pytest.approx(metrics.psnr(held_out, np.full((4, 6, 3), 0.5 + 0.5 / 512, np.float32)))
    assert points[-1]["kind"] == "bundle" and points[-1]["seconds_per_frame"] == pytest.approx(0.002)
    evaluate.error_vs_runtime(Field, [object()], 512, [32], 256, Bundle())
    assert sorted(rendered[3:]) == [32, 256, 512]       # without it the teacher's step count is rendered
