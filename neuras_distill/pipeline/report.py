"""The run's report: ``report.json`` (contract keys), ``report.md``, side-by-side images, and the plot of
error against run time (plus training PSNR against wall time)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .evaluate import side_by_side


def _mb(n) -> str:
    return "-" if n is None else f"{n / 1e6:.2f} MB"


def summary_table(rep: dict) -> str:
    """The before/after table printed at the end of a run."""
    w, h = rep["resolution"]
    ft = rep["frame_time_ms"]
    ratio = ""
    if rep.get("feature_bytes_vq") and rep.get("feature_bytes_float16"):
        ratio = f" ({rep['feature_bytes_float16'] / rep['feature_bytes_vq']:.1f}x smaller than float16 features)"
    rows = [
        ("", "before (field)", "after (bundle)"),
        ("renderer", "volume rendering", "OpenGL rasterization"),
        (f"FPS @ {w}x{h}", f"{rep['fps_before']:.3g}", f"{rep['fps_after']:.4g}"),
        ("frame time (median)", f"{ft['field_median']:.1f} ms", f"{ft['bundle_median']:.2f} ms"),
        ("PSNR / SSIM vs field", "reference", f"{rep['psnr']:.2f} dB / {rep['ssim']:.4f}"),
        ("OpenGL vs torch parity", "-", f"{rep['parity_psnr']:.1f} dB"),
        ("faces", "-", f"{rep['mesh_faces']}"),
        ("texture", "-", f"{rep['texture_resolution'][0]}x{rep['texture_resolution'][1]}x{rep['feature_dim']}, "
                         f"{rep['codebook_size']} codes"),
        ("bundle size", "-", _mb(rep.get("bundle_bytes")) + ratio),
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
                     + ", ".join(f"{r:.4g}" for r in sky["half_sizes"]) + f"; {sky['reason']}")
    for name, q in (rep.get("extrapolation") or {}).items():
        lines.append(f"lane shift {name}: {q['psnr']:.2f} dB / SSIM {q['ssim']:.4f}")
    if rep.get("ablation"):
        a = rep["ablation"]
        lines.append(f"ablation: without skyboxes {a['psnr_without_skyboxes']:.2f} dB "
                     f"(-{a['drop_db']:.2f} dB against {a['psnr_with_skyboxes']:.2f} dB with them)")
    for item in rep["left_out"]:
        lines.append(f"left out: {item['component']}: {item['reason']}")
    return "\n".join(lines)


def _skybox_lines(rep: dict) -> list[str]:
    sky = rep.get("skybox") or {}
    if not sky.get("used"):
        return []
    lines = ["## Skyboxes", "", f"{len(sky['half_sizes'])} cube layers around {[round(c, 3) for c in sky['center']]}, "
             "half sizes " + ", ".join(f"{r:.4g}" for r in sky["half_sizes"]) + f", {sky['resolution']}^2 texels "
             f"per face, {sky['num_codes']} codes. Why: {sky['reason']}.", ""]
    if rep.get("extrapolation"):
        lines += ["Lane shifts (held-out poses moved sideways; views/lane_*.png): "
                  + ", ".join(f"{k}: {q['psnr']:.2f} dB" for k, q in rep["extrapolation"].items()), ""]
    if rep.get("ablation"):
        a = rep["ablation"]
        lines += [f"Ablation: held-out PSNR {a['psnr_with_skyboxes']:.2f} dB with skyboxes, "
                  f"{a['psnr_without_skyboxes']:.2f} dB without ({a['drop_db']:.2f} dB drop; {a['how']}).", ""]
    return lines


def markdown(rep: dict) -> str:
    w, h = rep["resolution"]
    lines = [
        "# neuras-distill report", "",
        f"Held-out views: {rep['views']['test']} at {w}x{h}; trained on {rep['views']['train']} views at "
        f"{rep['views']['train_resolution'][0]}x{rep['views']['train_resolution'][1]}.", "",
        "| | before (field, volume rendering) | after (bundle, OpenGL) |", "|---|---|---|",
        f"| FPS @ {w}x{h} | {rep['fps_before']:.3g} | {rep['fps_after']:.4g} |",
        f"| speedup | | {rep['speedup']:.0f}x |",
        f"| PSNR vs field | reference | {rep['psnr']:.2f} dB |",
        f"| SSIM vs field | reference | {rep['ssim']:.4f} |",
        f"| LPIPS | | {rep['lpips'] if rep['lpips'] is not None else 'n/a: ' + rep.get('lpips_note', '')} |",
        f"| OpenGL vs torch forward (parity) | | {rep['parity_psnr']:.1f} dB |",
        f"| faces | | {rep['mesh_faces']} |",
        f"| texture | | {rep['texture_resolution'][0]}x{rep['texture_resolution'][1]}x{rep['feature_dim']}, "
        f"{rep['codebook_size']} codes |",
        f"| bundle | | {_mb(rep.get('bundle_bytes'))} |", "",
        f"Devices: field on {rep['device']['field']}; bundle on {rep['device']['bundle']}.", "",
        "## Time per stage", "", "| stage | seconds |", "|---|---|",
        *[f"| {k} | {v:.1f} |" for k, v in rep["stage_seconds"].items()],
        f"| total | {rep['distill_seconds']:.1f} |", "",
        *_skybox_lines(rep),
        "## Left out", "",
        *([f"- **{i['component']}**: {i['reason']}" for i in rep["left_out"]] or ["- nothing"]), "",
        "## Error against run time (first held-out view, against the field at twice the steps)", "",
        "| renderer | seconds/frame | PSNR |", "|---|---|---|",
        *[f"| {p['label']} | {p['seconds_per_frame']:.4f} | {p['psnr']:.2f} |" for p in rep["error_vs_runtime"]],
        "", "![error vs runtime](error_vs_runtime.png)", "",
        "## Held-out views (field | bundle | error x10)", "",
        *[f"![view {i}](views/view_{i:02d}.png) PSNR {p:.2f} dB" for i, p in enumerate(rep["psnr_per_view"])],
        "",
    ]
    return "\n".join(lines)


def plot(rep: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
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
    plt.close(fig)


def write_run_outputs(root: Path, rep: dict, field_images, bundle_images, extra_views: dict | None = None) -> None:
    """report.json, report.md, the error-vs-runtime plot and views/ (field | bundle | error per held-out view;
    ``extra_views`` {name: [(field, bundle), ...]} are saved as views/<name>_<i>.png)."""
    from PIL import Image

    views = root / "views"
    views.mkdir(exist_ok=True)
    for i, (f, b) in enumerate(zip(field_images, bundle_images)):
        Image.fromarray(side_by_side(f, b)).save(views / f"view_{i:02d}.png")
    for name, pairs in (extra_views or {}).items():
        for i, (f, b) in enumerate(pairs):
            Image.fromarray(side_by_side(f, b)).save(views / f"{name}_{i:02d}.png")
    plot(rep, root / "error_vs_runtime.png")
    (root / "report.json").write_text(json.dumps(rep, indent=2, default=_json_default))
    (root / "report.md").write_text(markdown(rep))


def _json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)
