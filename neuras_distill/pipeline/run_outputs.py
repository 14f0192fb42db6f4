"""The files a run writes about itself: ``report.json``, ``report.md``, ``report.html`` with its web player, the
error-vs-runtime plot and ``views/`` (side-by-side images and crops). The contents come from :mod:`.report`
(the blocks, tables and plots) and :mod:`.report_html` (the page); this module only writes them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .evaluate import crop_strip, side_by_side
from .report import flip_colors, markdown, plot
from .report_html import write_report_html


def write_run_outputs(root: Path, rep: dict, field_images, bundle_images, extra_views: dict | None = None,
                      flip_maps: list | None = None) -> None:
    """report.json, report.md, report.html with the web player web/ (``report_html``), the error-vs-runtime plot
    and views/: per held-out view field | bundle | error
    (| FLIP with ``flip_maps`` [(H, W) float32]), and then views/crop_<i>_a.png and _b.png, the windows
    ``rep["crops"]`` names; ``extra_views`` {name: [(field, bundle), ...]} are saved as
    views/<name>_<i>.png."""
    from PIL import Image

    views = root / "views"
    views.mkdir(exist_ok=True)
    crops = rep.get("crops") or []
    for i, (f, b) in enumerate(zip(field_images, bundle_images)):
        panel = flip_colors(flip_maps[i]) if flip_maps is not None else None
        Image.fromarray(side_by_side(f, b, flip_panel=panel)).save(views / f"view_{i:02d}.png")
        if panel is not None and i < len(crops):
            for key, c in crops[i].items():
                Image.fromarray(crop_strip(f, b, panel, c["box"])).save(views / f"crop_{i:02d}_{key}.png")
    for name, pairs in (extra_views or {}).items():
        for i, (f, b) in enumerate(pairs):
            Image.fromarray(side_by_side(f, b)).save(views / f"{name}_{i:02d}.png")
    plot(rep, root / "error_vs_runtime.png")
    (root / "report.json").write_text(json.dumps(rep, indent=2, default=_json_default))
    (root / "report.md").write_text(markdown(rep))
    write_report_html(root, rep)


def _json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)
