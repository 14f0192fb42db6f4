"""The run's report: ``report.json`` (contract keys), ``report.md`` (and ``report.html`` from the same blocks,
``report_html.py``), side-by-side images (field | bundle | error | FLIP), native-resolution crops of the worst
silhouette and interior areas, and the plot of error against run time (plus training PSNR against wall time). The
only module that imports matplotlib."""

from __future__ import annotations

from pathlib import Path

import numpy as np

CROP_NAMES = {"a": "silhouette band", "b": "interior"}



def _pages(rep: dict) -> str:
    """"P pages of " for an atlas in pages (``atlas_pages``; reports before it have none)."""
    pages = int(rep.get("atlas_pages") or 1)
    return f"{pages} pages of " if pages > 1 else ""

def _mb(n) -> str:
    return "-" if n is None else f"{n / 1e6:.2f} MB"


def _db(x) -> str:
    return "n/a" if x is None else f"{x:.2f} dB"


def _share(x) -> str:
    return "n/a" if x is None else f"{100 * x:.0f}%"


def _flip(x) -> str:
    return "n/a" if x is None else f"{x:.4f}"


def _fidelity_rows(rep: dict) -> list[tuple[str, str, str]]:
    """Rows of the summary table for FLIP, region PSNRs and holes (absent in reports without them)."""
    if "flip" not in rep:
        return []
    return [("FLIP vs field (0 = same)", "reference", f"{rep['flip']:.4f}"),
            ("PSNR interior / silhouette", "reference",
             f"{_db(rep['psnr_interior'])} / {_db(rep['psnr_silhouette'])}"),
            ("PSNR smooth region (field locally flat)", "reference",
             f"{_db(rep.get('psnr_smooth'))} on {_share(rep.get('smooth_fraction'))} of pixels"),
            ("PSNR / FLIP inside the box", "reference",
             f"{_db(rep.get('psnr_inside_box'))} / {_flip(rep.get('flip_inside_box'))}"),
            ("PSNR / FLIP outside the box", "reference",
             f"{_db(rep.get('psnr_outside_box'))} / {_flip(rep.get('flip_outside_box'))}"),
            ("holes (field opaque, no mesh)", "-", f"{100 * rep['hole_fraction']:.3f}% of pixels")]


def _plain_rows(rep: dict) -> list[tuple[str, str, str]]:
    """The plain-texture baseline's row (what the neural shader buys), when the report has one."""
    plain = rep.get("plain_texture")
    if not plain:
        return []
    return [("plain RGB texture instead", "-", f"{plain['psnr']:.2f} dB, FLIP {plain['flip']:.4f}, "
                                              f"{plain['frame_time_ms']:.2f} ms")]


def flip_colors(error_map: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 magma colours of an (H, W) FLIP map (0 black, 1 pale yellow); NaN pixels cyan."""
    import matplotlib

    lut = matplotlib.colormaps["magma"](np.linspace(0.0, 1.0, 256))[:, :3].astype(np.float32)
    e = np.asarray(error_map, dtype=np.float32)
    bad = ~np.isfinite(e)
    out = lut[np.clip(np.nan_to_num(e, nan=0.0) * 255 + 0.5, 0, 255).astype(np.int64)]
    out[bad] = (0.0, 1.0, 1.0)
    return out


def summary_table(rep: dict) -> str:
    """The before/after table printed at the end of a run."""
    w, h = rep["resolution"]
    ft = rep["frame_time_ms"]
    ratio = ""
    if rep.get("feature_bytes_vq") and rep.get("feature_bytes_float16"):
        factor = rep["feature_bytes_float16"] / rep["feature_bytes_vq"]
        ratio = (f" ({factor:.1f}x smaller than float16 features)" if factor >= 1.0 else
                 f" ({1.0 / factor:.1f}x the size of float16 features)")
    rows = [
        ("", "before (field)", "after (bundle)"),
        ("renderer", "volume rendering", "OpenGL rasterization"),
        (f"FPS @ {w}x{h}", f"{rep['fps_before']:.3g}", f"{rep['fps_after']:.4g}"),
        ("frame time (median)", f"{ft['field_median']:.1f} ms", f"{ft['bundle_median']:.2f} ms"),
        *([("  frames back to back", "-", f"{ft['bundle_pipelined']:.2f} ms")] if ft.get("bundle_pipelined") else []),
        *([("  GPU time (timer query)", "-", f"{ft['bundle_gpu_median']:.2f} ms")]
          if ft.get("bundle_gpu_median") else []),
        ("PSNR / SSIM vs field", "reference", f"{rep['psnr']:.2f} dB / {rep['ssim']:.4f}"),
        *_fidelity_rows(rep),
        ("OpenGL vs torch parity", "-", f"{rep['parity_psnr']:.1f} dB"),
        *_plain_rows(rep),
        ("faces", "-", f"{rep['mesh_faces']}"),
        ("texture", "-", _pages(rep) + f"{rep['texture_resolution'][0]}x{rep['texture_resolution'][1]}"
                         f"x{rep['feature_dim']}, "
                         f"{rep['codebook_size']} codes"),
        ("bundle size", "-", _mb(rep.get("bundle_bytes")) + ratio),
        *([("peak memory (run)", f"{rep['peak_rss_mb']:.0f} MB resident"
            + (f", {rep['peak_gpu_mb']:.0f} MB on the GPU" if rep.get("peak_gpu_mb") else ""), "")]
          if rep.get("peak_rss_mb") else []),
    ]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = ["", "  ".join(c.ljust(widths[i]) for i, c in enumerate(rows[0])),
             "  ".join("-" * wd for wd in widths)]
    lines += ["  ".join(c.ljust(widths[i]) for i, c in enumerate(r)) for r in rows[1:]]
    lines.append(f"speedup: {rep['speedup']:.0f}x    total: {rep['distill_seconds']:.1f} s    stages: "
                 + ", ".join(f"{k} {v:.1f}s" for k, v in rep["stage_seconds"].items()))
    sky = rep.get("skybox") or {}
    if sky.get("used"):
        lines.append(f"skyboxes: {len(sky['half_sizes'])} layers, half sizes "
                     + ", ".join(f"{r:.4g}" for r in sky["half_sizes"]) + _floors(sky) + f"; {sky['reason']}")
    for name, q in (rep.get("extrapolation") or {}).items():
        lines.append(f"lane shift {name}: {q['psnr']:.2f} dB / SSIM {q['ssim']:.4f}")
    if rep.get("ablation"):
        a = rep["ablation"]
        lines.append(f"ablation: without skyboxes {a['psnr_without_skyboxes']:.2f} dB "
                     f"(-{a['drop_db']:.2f} dB against {a['psnr_with_skyboxes']:.2f} dB with them)")
    stab = rep.get("stability")
    if stab:
        noted = [f"{it['name']} ({it['verdict']})" for it in stab["items"] if it["verdict"] != "fine"]
        raised = ", ".join(f"{k} {a} -> {b}" for k, (a, b) in stab.get("applied", {}).items())
        kept = ", ".join(f"{k} {a} (recommended {b})" for k, (a, b) in stab.get("not_applied", {}).items())
        lines.append(f"stability: {stab['verdict']}" + (f": {', '.join(noted)}" if noted else "")
                     + (f"; raised {raised}" if raised else "") + (f"; kept as configured {kept}" if kept else "")
                     + " (neuras-distill check)")
    for item in rep["left_out"]:
        lines.append(f"left out: {item['component']}: {item['reason']}")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------ report.md / report.html
# The report is a list of blocks, each a tuple whose first item names its kind; report.md (:func:`markdown`) and
# report.html (``report_html.py``) render the same blocks, so every table row and figure is written once:
#   ("heading", level, text)
#   ("para", text)                       text may hold **bold** spans
#   ("table", header, rows)              header and rows: tuples of cell strings
#   ("list", items)                      items: (text, figure or None); text may hold **bold** spans
#   ("figures", figures)                 figures: (src relative to the run folder, alt, caption or "")


def summary_rows(rep: dict) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """Header and rows of the report's before/after table."""
    w, h = rep["resolution"]
    plain = rep.get("plain_texture")
    rows = [
        (f"FPS @ {w}x{h}", f"{rep['fps_before']:.3g}", f"{rep['fps_after']:.4g}"),
        ("speedup", "", f"{rep['speedup']:.0f}x"),
        ("PSNR vs field", "reference", f"{rep['psnr']:.2f} dB"),
        ("SSIM vs field", "reference", f"{rep['ssim']:.4f}"),
        *([("FLIP vs field", "reference", f"{rep['flip']:.4f}")] if "flip" in rep else []),
        ("LPIPS", "", f"{rep['lpips'] if rep['lpips'] is not None else 'n/a: ' + rep.get('lpips_note', '')}"),
        ("OpenGL vs torch forward (parity)", "", f"{rep['parity_psnr']:.1f} dB"),
        *([("plain RGB texture instead of the neural shader", "",
            f"{plain['psnr']:.2f} dB, FLIP {plain['flip']:.4f}, {plain['frame_time_ms']:.2f} ms per frame")]
          if plain else []),
        ("faces", "", f"{rep['mesh_faces']}"),
        ("texture", "", _pages(rep) + f"{rep['texture_resolution'][0]}x{rep['texture_resolution'][1]}"
                         f"x{rep['feature_dim']}, "
                        f"{rep['codebook_size']} codes"),
        ("bundle", "", _mb(rep.get("bundle_bytes"))),
        *([("training stopped by", "", f"{stop['rule']}: {stop['why']}")] if (stop := rep.get("training_stop"))
          else []),
    ]
    return ("", "before (field, volume rendering)", "after (bundle, OpenGL)"), rows


def _floors(sky: dict) -> str:
    """", floors at h0, h1, ... along (up)" for skyboxes that lie on the ground (``SkyboxGround``), else ""."""
    ground = sky.get("ground")
    if not ground:
        return ""
    return (", floors at " + ", ".join(f"{h:.3g}" for h in ground["heights"])
            + f" along ({', '.join(f'{v:.3f}' for v in ground['normal'])})")


def _skybox_blocks(rep: dict) -> list[tuple]:
    sky = rep.get("skybox") or {}
    if not sky.get("used"):
        return []
    blocks = [("heading", 2, "Skyboxes"),
              ("para", f"{len(sky['half_sizes'])} cube layers around {[round(c, 3) for c in sky['center']]}, "
                       "half sizes " + ", ".join(f"{r:.4g}" for r in sky["half_sizes"]) + _floors(sky)
                       + f", {sky['resolution']}^2 texels per face, {sky['num_codes']} codes. "
                       f"Why: {sky['reason']}.")]
    if rep.get("extrapolation"):
        blocks.append(("para", "Lane shifts (held-out poses moved sideways; views/lane_*.png): "
                       + ", ".join(f"{k}: {q['psnr']:.2f} dB" for k, q in rep["extrapolation"].items())))
    if rep.get("ablation"):
        a = rep["ablation"]
        blocks.append(("para", f"Ablation: held-out PSNR {a['psnr_with_skyboxes']:.2f} dB with skyboxes, "
                               f"{a['psnr_without_skyboxes']:.2f} dB without ({a['drop_db']:.2f} dB drop; "
                               f"{a['how']})."))
    return blocks


def _fidelity_blocks(rep: dict) -> list[tuple]:
    """Section: definitions, per-view FLIP / region PSNR / holes, and what each crop shows."""
    if "flip" not in rep:
        return []
    band = rep.get("silhouette_band_px")
    smooth = rep.get("psnr_smooth_per_view") or [None] * len(rep["flip_per_view"])
    rows = [(f"{i}", f"{fl:.4f}", _db(rep["psnr_per_view"][i]), _db(rep["psnr_interior_per_view"][i]),
             _db(rep["psnr_silhouette_per_view"][i]), _db(smooth[i]), f"{100 * rep['hole_fraction_per_view'][i]:.3f}%")
            for i, fl in enumerate(rep["flip_per_view"])]
    rows.append(("mean", f"{rep['flip']:.4f}", _db(rep["psnr"]), _db(rep["psnr_interior"]),
                 _db(rep["psnr_silhouette"]), _db(rep.get("psnr_smooth")), f"{100 * rep['hole_fraction']:.3f}%"))
    crops = []
    for i, view_crops in enumerate(rep.get("crops") or []):
        for key, name in CROP_NAMES.items():
            c = view_crops.get(key)
            if c is None:
                crops.append((f"view {i}, {name}: none (the view has no {name} pixels)", None))
                continue
            x0, y0, cw, ch = c["box"]
            crops.append((f"view {i}, {name} (worst FLIP, mean {c['flip']:.4f} on its {name} pixels), "
                          f"x {x0}-{x0 + cw}, y {y0}-{y0 + ch}:",
                          (f"views/crop_{i:02d}_{key}.png", f"view {i} {name}", "")))
    return [
        ("heading", 2, "Fidelity by region"),
        ("para", "Regions come from the field's own opacity of each held-out view. "
                 f"**Silhouette band**: pixels within {band} px of the boundary of the field's mask "
                 "(opacity > 0.5), on either side, plus every pixel with 0.02 < opacity < 0.98 (the soft fringe); "
                 "the width is max(2, round(0.004 x image diagonal)). "
                 "**Interior**: opacity > 0.98 and not in the band. "
                 "**Smooth**: pixels whose 5x5 neighbourhood in the field's image has a luma standard deviation "
                 "below 0.01 (flat walls, sky, plain floor: where mottling shows). "
                 "**Holes**: pixels where the field is opaque (opacity > 0.5) but the bundle's mesh "
                 "covers nothing (rasterized as played), as a fraction of all held-out pixels. "
                 "**FLIP**: NVIDIA's LDR-FLIP perceptual error (0 = no visible difference, 1 = maximal), at its "
                 "default 67 pixels per degree; means are means of per-view values."),
        ("table", ("view", "FLIP", "PSNR", "PSNR interior", "PSNR silhouette", "PSNR smooth", "holes"), rows),
        ("para", "Crops at native resolution (field | bundle | FLIP, magma: black 0 to pale yellow 1), each "
                 "centred where the FLIP map, box-filtered over 32x32 pixels of one region, is highest:"),
        ("list", crops),
    ]


def report_blocks(rep: dict) -> list[tuple]:
    """The report as blocks (see above): what report.md and report.html both show."""
    w, h = rep["resolution"]
    header, rows = summary_rows(rep)
    stages = [(k, f"{v:.1f}") for k, v in rep["stage_seconds"].items()]
    stages.append(("total", f"{rep['distill_seconds']:.1f}"))
    runtime = [(p["label"], f"{p['seconds_per_frame']:.4f}", f"{p['psnr']:.2f}") for p in rep["error_vs_runtime"]]
    left_out = [(f"**{i['component']}**: {i['reason']}", None) for i in rep["left_out"]] or [("nothing", None)]
    views = [(f"views/view_{i:02d}.png", f"view {i}", f"PSNR {p:.2f} dB")
             for i, p in enumerate(rep["psnr_per_view"])]
    return [
        ("heading", 1, "neuras-distill report"),
        ("para", f"Held-out views: {rep['views']['test']} at {w}x{h}; trained on {rep['views']['train']} views at "
                 f"{rep['views']['train_resolution'][0]}x{rep['views']['train_resolution'][1]}."),
        ("table", header, rows),
        ("para", f"Devices: field and teacher on {rep['device']['field']}; training on "
                 f"{rep['device'].get('training', rep['device']['field'])}; bundle on {rep['device']['bundle']}."
                 + (f" {rep['device']['bundle_note']}." if rep['device'].get('bundle_note') else "")),
        ("heading", 2, "Time per stage"),
        ("table", ("stage", "seconds"), stages),
        *_skybox_blocks(rep),
        ("heading", 2, "Left out"),
        ("list", left_out),
        ("heading", 2, "Error against run time (first held-out view, against the field at twice the steps)"),
        ("table", ("renderer", "seconds/frame", "PSNR"), runtime),
        ("figures", [("error_vs_runtime.png", "error vs runtime", "")]),
        *_fidelity_blocks(rep),
        ("heading", 2, "Held-out views (field | bundle | error x10" + (" | FLIP" if "flip" in rep else "") + ")"),
        ("figures", views),
    ]


def _md_row(cells) -> str:
    return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"


def _md_figure(fig) -> str:
    src, alt, caption = fig
    return f"![{alt}]({src})" + (f" {caption}" if caption else "")


def markdown(rep: dict) -> str:
    """report.md: the blocks of :func:`report_blocks` as Markdown, each followed by a blank line."""
    return blocks_markdown(report_blocks(rep))


def blocks_markdown(blocks: list[tuple]) -> str:
    """Report blocks (heading, para, table, list, figures) as Markdown, each followed by a blank line."""
    lines = []
    for block in blocks:
        kind = block[0]
        if kind == "heading":
            lines.append("#" * block[1] + " " + block[2])
        elif kind == "para":
            lines.append(block[1])
        elif kind == "table":
            lines += [_md_row(block[1]), "|" + "---|" * len(block[1])] + [_md_row(r) for r in block[2]]
        elif kind == "list":
            lines += [f"- {text}" + (f" {_md_figure(fig)}" if fig else "") for text, fig in block[1]]
        elif kind == "figures":
            lines += [_md_figure(fig) for fig in block[1]]
        else:
            raise ValueError(f"unknown report block {kind!r}")
        lines.append("")
    return "\n".join(lines)


def _figure(rows: int, cols: int, figsize: tuple[float, float]):
    """(Figure, axes (rows, cols)) drawn by Agg through matplotlib's object API: no pyplot, no global backend,
    so a notebook's own backend and figures are left as they are."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(rows, cols, squeeze=False)


def plot(rep: dict, path: Path) -> None:
    fig, grid = _figure(1, 2, (11, 4))
    axes = grid[0]
    ax = axes[0]
    pts = rep["error_vs_runtime"]
    field_pts = [p for p in pts if p["kind"] == "field"]
    ax.plot([p["seconds_per_frame"] for p in field_pts], [p["psnr"] for p in field_pts], "o-", label="field")
    for p in field_pts:
        ax.annotate(str(p["steps"]), (p["seconds_per_frame"], p["psnr"]), textcoords="offset points",
                    xytext=(4, 4), fontsize=8)
    bundle_pts = [p for p in pts if p["kind"] == "bundle"]
    ax.plot([p["seconds_per_frame"] for p in bundle_pts], [p["psnr"] for p in bundle_pts], "s", color="C3",
            markersize=9, label="bundle (OpenGL)")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per frame (log)")
    ax.set_ylabel("PSNR vs reference (dB)")
    ax.set_title(f"error vs run time @ {rep['resolution'][0]}x{rep['resolution'][1]}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax = axes[1]
    log = [e for e in rep.get("train_log", []) if "seconds" in e and "psnr" in e]
    if log:
        ax.plot([e["seconds"] for e in log], [e["psnr"] for e in log], "-")
    ax.set_xlabel("training wall time (s)")
    ax.set_ylabel("training PSNR (dB)")
    ax.set_title("distillation")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_tradeoff(points: list[dict], fronts: dict, path: Path) -> None:
    """The bench's plot, one column per resolution. Top: PSNR against milliseconds per frame (log) for the
    field's step counts (a line), the plain-texture floor and every bundle; the Pareto front dashed, the default
    starred; only the front, the default and the floor labelled. Bottom: the bundles alone on linear axes, every
    one labelled from a column beside the cluster (variants often lie within a millisecond and a tenth of a dB
    of each other)."""
    keys = list(fronts)
    fig, axes = _figure(2, len(keys), (6.5 * len(keys), 10))
    for col, key in enumerate(keys):
        ax, zoom = axes[0][col], axes[1][col]
        here = [p for p in points if f"{p['resolution'][0]}x{p['resolution'][1]}" == key]
        ms = {p["label"]: 1000.0 * p["seconds_per_frame"] for p in here}
        field = [p for p in here if p["kind"] == "field"]
        ax.plot([ms[p["label"]] for p in field], [p["psnr"] for p in field], "o-", color="C0", label="field")
        for p in field:
            ax.annotate(f"{p['steps']} steps", (ms[p["label"]], p["psnr"]), textcoords="offset points",
                        xytext=(4, -10), fontsize=7)
        rasterized = [p for p in here if p["kind"] != "field"]
        for p in rasterized:
            style = _tradeoff_style(p)
            for target in (ax, zoom) if p["kind"] == "bundle" else (ax,):
                target.plot([ms[p["label"]]], [p["psnr"]], style[0], color=style[1], markersize=style[2],
                            zorder=3 if p["default"] else 2)
            if p["default"] or p["kind"] == "plain-texture" or p["label"] in fronts[key]:
                ax.annotate(p["label"], (ms[p["label"]], p["psnr"]), textcoords="offset points", xytext=(5, 3),
                            fontsize=7)
        front = [next(p for p in here if p["label"] == label) for label in fronts[key]]
        ax.plot([ms[p["label"]] for p in front], [p["psnr"] for p in front], "--", color="0.5", lw=1,
                label="Pareto front")
        ax.plot([], [], "*", color="C3", markersize=12, label="default bundle")
        ax.plot([], [], "s", color="C1", label="bundle variants")
        ax.plot([], [], "D", color="C2", label="plain texture (floor)")
        ax.set_xscale("log")
        ax.set_xlabel("milliseconds per frame (log)")
        ax.set_ylabel(f"PSNR vs the field at {here[0]['reference_steps']} steps (dB)")
        ax.set_title(f"error vs run time @ {key}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
        _label_column(zoom, [(p["label"] + (" (default)" if p["default"] and p["label"] != "default" else ""),
                             ms[p["label"]], p["psnr"])
                             for p in rasterized if p["kind"] == "bundle"])
        zoom.set_xlabel("milliseconds per frame")
        zoom.set_ylabel("PSNR (dB)")
        zoom.set_title(f"the bundles @ {key}")
        zoom.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _tradeoff_style(point: dict) -> tuple[str, str, int]:
    """(marker, colour, size) of a rasterized point: default starred, floor a diamond, variants squares."""
    if point["default"]:
        return "*", "C3", 15
    return ("D", "C2", 8) if point["kind"] == "plain-texture" else ("s", "C1", 7)


def _label_column(ax, points: list[tuple[str, float, float]]) -> None:
    """Label ``points`` (label, x, y) from a column right of them, evenly spaced in the points' y order, each
    joined to its point by a thin line: no two labels overlap however close the points are."""
    if not points:
        return
    xs, ys = [x for _, x, _ in points], [y for _, _, y in points]
    x0, x1 = min(xs), max(xs)
    y0, y1 = min(ys), max(ys)
    span_x, span_y = max(x1 - x0, 1e-3), max(y1 - y0, 0.1)
    column = x1 + 0.15 * span_x
    ordered = sorted(points, key=lambda t: t[2])
    slots = [y0 - 0.05 * span_y + (1.1 * span_y) * i / max(len(ordered) - 1, 1) for i in range(len(ordered))]
    for (label, x, y), slot in zip(ordered, slots):
        ax.annotate(label, (x, y), xytext=(column, slot), textcoords="data", fontsize=7, va="center",
                    arrowprops={"arrowstyle": "-", "color": "0.6", "lw": 0.6})
    ax.set_xlim(x0 - 0.1 * span_x, x1 + 0.75 * span_x)
    ax.set_ylim(min(y0, slots[0]) - 0.07 * span_y, max(y1, slots[-1]) + 0.07 * span_y)
