"""The bench's files: ``bench.json`` (the points), ``bench.md`` and ``bench.png`` (the plot), and its section
in the run's ``report.html`` (the same blocks as bench.md, rendered by ``pipeline.report_html``)."""

from __future__ import annotations

import json
from pathlib import Path

SECTION_START, SECTION_END = "<!-- bench:start -->", "<!-- bench:end -->"


def _ms(p: dict) -> str:
    t = p.get("timing") or {}
    spread = f" ({t['p10_ms']:.2f}-{t['p90_ms']:.2f})" if "p10_ms" in t else ""
    return f"{1000.0 * p['seconds_per_frame']:.2f}{spread}"


def bench_blocks(result: dict, image_prefix: str = "") -> list[tuple]:
    """bench.md's content as report blocks (``pipeline.report.blocks_markdown``)."""
    blocks: list[tuple] = [("heading", 1, "Error against run time (neuras-distill bench)")]
    m = result["machine"]
    gl = (m.get("gl") or {}).get("renderer", "unknown")
    blocks.append(("para", f"Run `{result['run']}`; {m['cpu_count']} CPU cores, torch {m['torch']} with "
                           f"{m['torch_threads']} threads, OpenGL renderer {gl}; bench wall time "
                           f"{result['seconds'] / 60:.1f} min. Every point is scored on all held-out views against "
                           "the field marched with twice the steps of its densest point; times are medians "
                           "(10th-90th percentile in brackets) of GL frames timed with glFinish after 5 warm-up "
                           "frames (>= 30 frames), and of one field frame per view after one warm-up frame."))
    blocks.append(("figures", [(f"{image_prefix}bench.png", "error vs run time", "")]))
    for key, front in result["pareto_by_resolution"].items():
        here = [p for p in result["points"] if f"{p['resolution'][0]}x{p['resolution'][1]}" == key]
        blocks.append(("heading", 2, f"{key}"))
        rows = []
        for p in sorted(here, key=lambda p: p["seconds_per_frame"]):
            name = p["label"] + (" **(default)**" if p["default"] else "")
            rows.append((name, p["kind"], _ms(p), f"{p['psnr']:.2f}", f"{p['ssim']:.4f}", f"{p['flip']:.4f}",
                         "" if p.get("bundle_bytes") is None else f"{p['bundle_bytes'] / 1e6:.2f}",
                         "yes" if p["label"] in front else ""))
        blocks.append(("table", ("point", "kind", "ms per frame", "PSNR (dB)", "SSIM", "FLIP", "bundle MB",
                                 "on the front"), rows))
        default = next((p for p in here if p["default"]), None)
        plain = next((p for p in here if p["kind"] == "plain-texture"), None)
        if default and plain:
            share = plain["seconds_per_frame"] / default["seconds_per_frame"]
            blocks.append(("para", f"The default bundle plays at {100 * share:.0f}% of the plain-texture floor's "
                                   f"frame rate ({_ms(default)} against {_ms(plain)} ms) and scores "
                                   f"{default['psnr'] - plain['psnr']:+.2f} dB against it."))
    pick = result.get("recommended")
    if pick:
        advice = f"`{pick}`."
    else:
        largest = max(result["points"], key=lambda p: p["resolution"][0] * p["resolution"][1])["resolution"]
        bundles = [p for p in result["points"] if p["kind"] == "bundle" and p["resolution"] == largest]
        fastest = min(bundles, key=lambda p: p["seconds_per_frame"]) if bundles else None
        advice = "no bundle is that fast on this machine" + (
            f"; the fastest is `{fastest['label']}` at {1000 * fastest['seconds_per_frame']:.2f} ms "
            f"({fastest['psnr']:.2f} dB)." if fastest else ".")
    blocks.append(("para", f"**Recommended for {result['target_ms']:.1f} ms per frame** at the largest resolution: "
                           + advice))
    if result.get("skipped"):
        blocks.append(("list", [(f"{name} skipped: {why}", None) for name, why in result["skipped"].items()]))
    blocks.append(("list", [(f"`{name}`: {v['description']} (config changes {json.dumps(v['changes'])})", None)
                            for name, v in result["variants"].items()]))
    return blocks


def write_outputs(result: dict, folder: Path) -> None:
    """bench.json, bench.md and bench.png in ``folder``."""
    from ..pipeline.report import blocks_markdown, plot_tradeoff

    folder = Path(folder)
    (folder / "bench.json").write_text(json.dumps(result, indent=2))
    plot_tradeoff(result["points"], result["pareto_by_resolution"], folder / "bench.png")
    (folder / "bench.md").write_text(blocks_markdown(bench_blocks(result)))


def add_to_report_html(run: Path, result: dict) -> None:
    """Put (or replace) the bench's section at the end of the run's report.html, when it has one."""
    from ..pipeline.report_html import block_html

    page = Path(run) / "report.html"
    if not page.is_file():
        return
    text = page.read_text("utf-8")
    if SECTION_START in text:
        head, _, rest = text.partition(SECTION_START)
        text = head + rest.partition(SECTION_END)[2]
    section = (SECTION_START + '<section id="bench">' + "\n".join(block_html(b) for b in bench_blocks(result, "bench/"))
               + "</section>" + SECTION_END + "\n")
    text = text.replace("</body>", section + "</body>", 1) if "</body>" in text else text + section
    page.write_text(text, "utf-8")
