"""The results table of docs/results.md, from run folders' ``report.json``.

    python benchmarks/results_table.py RUN_DIR [RUN_DIR ...]                 # print the table
    python benchmarks/results_table.py RUN_DIR ... --out docs/results.md     # write the page

Each argument is a run folder (the ``--out`` of a run command) or a ``report.json``-shaped file. One row per
run: the command that made it (``report["source"]``), where it ran (``device``), the held-out resolution, PSNR,
FLIP, PSNR in the interior, in the silhouette band and in smooth regions (each where the report has it), the
speedup (bundle frames per second over the field's), the wall time of the pipeline (``distill_seconds``), and
the commit and date the report records (``commit``, ``created``).

``benchmarks/recorded/`` holds report-shaped records of the figures this page publishes (a subset of each
run's report.json); ``tests/test_repository_text.py`` checks that docs/results.md is this script's output on
them. To publish a new figure, add its run's report.json there (or a record of its keys) and run
``python benchmarks/results_table.py benchmarks/recorded/*.json --out docs/results.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RECORDED = ROOT / "benchmarks" / "recorded"

#: Report keys of the PSNR in smooth regions, first one present wins (absent from reports that predate it).
SMOOTH_KEYS = ("psnr_smooth", "psnr_smooth_region", "psnr_smooth_interior")

HEADER = ("| scene | device | resolution | PSNR | FLIP | interior | silhouette | smooth | speedup | wall | commit "
          "| date |")
RULE = "|" + "---|" * 12


def load_report(path: str | Path) -> dict:
    """The report of a run folder or a report.json-shaped file, with ``_path`` set to where it came from."""
    path = Path(path)
    file = path / "report.json" if path.is_dir() else path
    if not file.is_file():
        raise SystemExit(f"{path}: no report.json (give a run folder or a report.json file)")
    try:
        report = json.loads(file.read_text())
    except json.JSONDecodeError as exc:
        raise SystemExit(f"{file}: not JSON ({exc})") from None
    if not isinstance(report, dict) or "psnr" not in report:
        raise SystemExit(f"{file}: not a run report (it has no 'psnr')")
    report["_path"] = str(file)
    return report


def scene_label(report: dict) -> str:
    """The command without the program name and its ``--out``/``--quiet`` options, e.g. ``from-ngp ball.ingp``."""
    command = list((report.get("source") or {}).get("command") or [])
    if not command:
        return (report.get("source") or {}).get("python", "python API")
    words, skip = [], False
    for word in command[1:]:
        if skip:
            skip = False
            continue
        if word in ("--out", "--device"):
            skip = True
            continue
        if word.startswith("--out=") or word.startswith("--device=") or word in ("--quiet", "--fresh"):
            continue
        words.append(word)
    return " ".join(words)


def device_label(report: dict) -> str:
    """Where the field ran and what OpenGL played the bundle: ``CPU, 2 threads / llvmpipe``."""
    device = report.get("device") or {}
    field = str(device.get("field", "?"))
    if field.startswith("GPU: "):
        where = field[5:].split(" (")[0]
    elif field.startswith("CPU: ") and "threads)" in field:
        where = "CPU, " + field.split("(")[-1].split(")")[0]
    else:
        where = field
    gl = str(device.get("bundle", ""))
    gl = gl.removeprefix("OpenGL: ").split(" (")[0].strip()
    return f"{where} / {gl}" if gl else where


def _num(value, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def _wall(seconds) -> str:
    if seconds is None:
        return "-"
    return f"{seconds:.0f} s" if seconds < 120 else f"{seconds / 60:.1f} min"


def _date(report: dict) -> str:
    created = report.get("created")
    if created:
        return str(created)[:10]
    path = report.get("_path")
    if path and Path(path).is_file() and "recorded" not in Path(path).parts:
        return time.strftime("%Y-%m-%d", time.gmtime(Path(path).stat().st_mtime))
    return "-"


def row(report: dict) -> str:
    w, h = report.get("resolution") or (None, None)
    smooth = next((report[k] for k in SMOOTH_KEYS if report.get(k) is not None), None)
    speedup = report.get("speedup")
    cells = [f"`{scene_label(report)}`", device_label(report), f"{w}x{h}" if w else "-",
             _num(report.get("psnr"), ".2f"), _num(report.get("flip"), ".4f"),
             _num(report.get("psnr_interior"), ".2f"), _num(report.get("psnr_silhouette"), ".2f"),
             _num(smooth, ".2f"), "-" if speedup is None else f"{speedup:.0f}x",
             _wall(report.get("distill_seconds")), report.get("commit") or "-", _date(report)]
    return "| " + " | ".join(cells) + " |"


def table(reports: list[dict]) -> str:
    return "\n".join([HEADER, RULE, *(row(r) for r in reports)])


def page(reports: list[dict]) -> str:
    notes = [r for r in reports if r.get("note")]
    lines = [
        "# Results",
        "",
        "<!-- Generated by `python benchmarks/results_table.py benchmarks/recorded/*.json --out docs/results.md`",
        "     from the runs' report.json records in benchmarks/recorded/; do not edit by hand. -->",
        "",
        "Each row is one run of the command shown, on the device shown (where the field and training ran / the",
        "OpenGL renderer that played the bundle). Scores compare the bundle played by OpenGL with the field's own",
        "volume rendering on held-out cameras at the resolution shown: PSNR in dB over the whole frame, FLIP",
        "(NVIDIA's perceptual error, 0 = identical), PSNR where the field is opaque away from its silhouettes",
        "(interior), in a band around the silhouettes (silhouette) and in smooth regions (where the report has",
        "it). Speedup is the bundle's frames per second over the field's, same cameras and resolution; wall is",
        "the pipeline's time (`distill_seconds`; `-` where the figure came from a re-run on stored stages).",
        "Commit and date are those the run recorded.",
        "",
        table(reports),
        "",
    ]
    if notes:
        lines += ["Notes:", ""]
        lines += [f"- `{scene_label(r)}` on {device_label(r)}: {r['note']}" for r in notes]
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="the results table from run folders' report.json")
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR", help="run folders or report.json files")
    parser.add_argument("--out", default=None, help="write the whole page (docs/results.md) here")
    args = parser.parse_args(argv)
    reports = [load_report(p) for p in args.runs]
    if args.out:
        Path(args.out).write_text(page(reports))
        print(f"wrote {args.out} ({len(reports)} runs)")
    else:
        print(table(reports))
    return 0


if __name__ == "__main__":
    sys.exit(main())
