"""The report's plots leave the caller's matplotlib alone: drawn through the object API (``Figure`` +
``FigureCanvasAgg``), never ``matplotlib.use`` or pyplot, so a notebook keeps its backend."""

from __future__ import annotations

import numpy as np
from PIL import Image


def test_plots_draw_without_switching_the_backend(tmp_path):
    import matplotlib

    from neuras_distill.pipeline.report import plot, plot_tradeoff

    matplotlib.use("svg")                  # what a caller chose (a notebook's inline backend, say)
    before = matplotlib.get_backend()
    rep = {"resolution": [64, 48], "train_log": [{"seconds": 1.0, "psnr": 20.0}, {"seconds": 2.0, "psnr": 25.0}],
           "error_vs_runtime": [{"kind": "field", "steps": 32, "seconds_per_frame": 0.5, "psnr": 30.0},
                                {"kind": "field", "steps": 64, "seconds_per_frame": 1.0, "psnr": 35.0},
                                {"kind": "bundle", "seconds_per_frame": 0.002, "psnr": 33.0}]}
    plot(rep, tmp_path / "plot.png")
    points = [{"label": "field-32", "kind": "field", "steps": 32, "resolution": [64, 48], "seconds_per_frame": 0.5,
               "psnr": 30.0, "reference_steps": 64, "default": False},
              {"label": "default", "kind": "bundle", "resolution": [64, 48], "seconds_per_frame": 0.002,
               "psnr": 33.0, "reference_steps": 64, "default": True}]
    plot_tradeoff(points, {"64x48": ["default"]}, tmp_path / "front.png")
    assert matplotlib.get_backend() == before
    for name in ("plot.png", "front.png"):
        image = np.asarray(Image.open(tmp_path / name).convert("L"))
        assert image.shape[0] > 200 and image.std() > 10          # drawn: axes and points on white
