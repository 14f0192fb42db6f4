"""``bench(run_dir)``: the whole trade-off of one run, written to ``<run>/bench/``.

Order: check the run folder (a finished run of this version with its work area and recorded command), rebuild
its field from ``report["source"]`` (the command line and its folder), distil each variant into
``bench/variants/<name>/`` from the run's stored stages (``distill(reuse_from=[<run>/work])``), then measure
every point at each resolution (:mod:`.measure`) and write ``bench.json``, ``bench.md``, ``bench.png`` and a
section of the run's ``report.html``. Everything is written in ``<run>/.bench.partial/`` and moved to
``<run>/bench/`` when it is complete; a failed bench leaves the run as it was. A bench that was killed is
resumed by the same command: each variant finished in ``.bench.partial/variants/`` carries a marker with the
settings it was distilled with (:data:`VARIANT_MARKER`) and is reused when they match; the measurements are
taken again (they must come from one sitting).
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import BadInputError, require
from .front import pareto_front, recommend
from .variants import RunFacts, pick_variants, variant_overrides

#: Resolutions benched when none are given.
DEFAULT_RESOLUTIONS = ((640, 360), (1920, 1080))
#: Field step counts below the teacher's (the teacher's own is always added).
FIELD_STEPS = (32, 64, 128)
#: Frame time the recommendation aims at when none is given (60 Hz).
DEFAULT_TARGET_MS = 1000.0 / 60.0


#: Parts of each variant's run folder the bench removes (its side-by-side images and web player); the bundle,
#: report.json/md and the stage timings stay in ``bench/variants/NAME/``.
VARIANT_FOLDERS_DROPPED = ("views", "web")
#: File in each finished variant's folder naming what it was distilled from (run source, settings, version).
VARIANT_MARKER = "bench_variant.json"


def parse_resolutions(text: str) -> list[tuple[int, int]]:
    """``"640x360,1920x1080"`` -> [(640, 360), (1920, 1080)]; sides 8..8192."""
    out = []
    for part in [p.strip() for p in str(text).split(",") if p.strip()]:
        w, sep, h = part.lower().partition("x")
        if not sep or not w.isdigit() or not h.isdigit():
            raise BadInputError(f"--resolutions: {part!r} is not WIDTHxHEIGHT (e.g. 640x360,1920x1080)")
        w, h = int(w), int(h)
        require(8 <= w <= 8192 and 8 <= h <= 8192,
                f"--resolutions: {part!r} is outside 8x8 .. 8192x8192 pixels")
        out.append((w, h))
    require(bool(out), "--resolutions is empty; pass e.g. 640x360,1920x1080")
    return out


def _read_run(run: Path, need_command: bool = True) -> dict:
    from .. import __version__

    require(run.is_dir(), f"{run} is not a folder; pass a run folder (runs/<scene>)")
    report_path = run / "report.json"
    require((run / ".neuras-distill-run").is_file() and report_path.is_file() and (run / "bundle").is_dir(),
            f"{run} is not a neuras-distill run folder (no report.json and bundle/); pass the --out of a run")
    try:
        report = json.loads(report_path.read_text())
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{report_path} cannot be read ({exc}); re-run the distillation") from None
    command = (report.get("source") or {}).get("command")
    again = ("re-run it with the same command (its stages are stored in <run>/work, which the bench reuses)"
             if command else "re-run it with neuras-distill demo / from-synthetic / from-ngp / from-sdf")
    require(report.get("version") == __version__ and (run / "work").is_dir() and "work_area" in report,
            f"{run} was made by neuras-distill {report.get('version', 'before 0.4')} without a stored work "
            f"area, which the bench distils its variants from; {again}")
    require(bool(command) or not need_command,
            f"{run} was made from Python, so the bench cannot rebuild its field; call "
                           "neuras_distill.bench.bench(run, field=..., cameras=...) with the same field, or run it "
                           "with the neuras-distill command")
    require((run / "cameras.json").is_file(), f"{run} has no cameras.json; {again}")
    return report


@contextmanager
def _in_folder(folder: str | None):
    old = os.getcwd()
    if folder and Path(folder).is_dir():
        os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(old)


def rebuild_inputs(report: dict) -> tuple:
    """(field, cameras or None) the run's recorded command distilled, loaded in the folder it ran in."""
    from ..cli_parser import build_parser
    from ..run_inputs import RUN_COMMANDS, run_inputs

    argv = list(report["source"]["command"][1:])
    try:
        args = build_parser().parse_args(argv)
    except SystemExit:
        raise BadInputError(f"the run's recorded command {' '.join(argv)!r} is not one this version reads; "
                            "re-run the distillation") from None
    require(args.command in RUN_COMMANDS, f"the run's recorded command {args.command!r} does not distil a field")
    with _in_folder(report["source"].get("cwd")):
        field, cameras, _ = run_inputs(args)
    return field, cameras


def _facts(report: dict) -> RunFacts:
    tex = report["config"]["texture"]
    side = (report.get("mesh_stats") or {}).get("uv_resolution") or report["texture_resolution"][0]  # atlas, not page
    return RunFacts(side=int(side), steps=int(report["train_summary"]["steps"]),
                    face_budget=int(report["config"]["geometry"]["face_budget"]), hidden=int(tex["hidden"]),
                    num_layers=int(tex["num_layers"]),
                    view_input=bool((report.get("view_dependence") or {}).get("used", True)))


def _merged(base: dict, changes: dict) -> dict:
    out = json.loads(json.dumps(base))
    for section, values in changes.items():
        out.setdefault(section, {}).update(values)
    return out


def _clear_all_but_variants(tmp: Path) -> None:
    """Empty a killed bench's ``.bench.partial/`` except ``variants/`` (whose finished members are reused)."""
    if not tmp.is_dir():
        return
    for entry in tmp.iterdir():
        if entry.name == "variants" and entry.is_dir():
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def _finished_variant(folder: Path, marker: dict) -> dict | None:
    """The report of a variant a killed bench finished with exactly ``marker``'s settings, else None.

    The marker is written last, after the variant's run folder appeared (atomically) and its heavy folders were
    dropped, so its presence means the variant is complete.
    """
    try:
        stored = json.loads((folder / VARIANT_MARKER).read_text())
        if stored != json.loads(json.dumps(marker, sort_keys=True)):
            return None
        return json.loads((folder / "report.json").read_text())
    except (OSError, ValueError):
        return None


def _machine(gl: dict | None) -> dict:
    import torch

    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(), "torch": torch.__version__,
            "gl": gl}


def bench(run_dir, *, resolutions=None, variants: list[str] | None = None, target_ms: float | None = None,
          field=None, cameras=None, progress: bool = True, log=None) -> dict:
    """Bench a finished run; returns ``bench.json``'s content (see the module docstring and docs/contract.md).

    Args:
        run_dir: a run folder written by a run command of this version (report.json, bundle/, work/).
        resolutions: "WxH,WxH" or [(w, h), ...] (default 640x360 and 1920x1080; the held-out cameras' aspect).
        variants: names from ``bench.variants.VARIANT_NAMES`` (default all).
        target_ms: frame time the recommendation aims at (default 16.7 ms, 60 Hz).
        field, cameras: the run's field and cameras when it was made from Python (default: rebuilt from the
            command the run recorded).
    """
    from ..bake.bundle import load_bundle
    from ..bake.plain_texture import plain_bundle
    from ..config import load_config
    from ..pipeline.run import distill
    from ..playback.context import gl_info
    from ..render.cameras import Cameras
    from .measure import GLEntry, field_points, gl_points, render_reference

    t_start = time.perf_counter()
    if log is None:
        from ..logs import say as log
    run = Path(run_dir)
    res = parse_resolutions(resolutions) if isinstance(resolutions, str) else list(resolutions or DEFAULT_RESOLUTIONS)
    chosen = pick_variants(variants)
    target = DEFAULT_TARGET_MS if target_ms is None else float(target_ms)
    require(target > 0, f"--target-ms must be positive, got {target_ms}")
    report = _read_run(run, need_command=field is None)
    test = Cameras.from_json(json.loads((run / "cameras.json").read_text())["test"])
    for w, h in res:
        require(abs(w / h - test.width / test.height) <= 0.01 * test.width / test.height,
                f"--resolutions {w}x{h} does not match the held-out cameras' aspect ratio "
                f"({test.width}x{test.height}); use e.g. {w}x{round(w * test.height / test.width)}")
    if field is None:
        field, cameras = rebuild_inputs(report)
    facts = _facts(report)
    teacher_steps = int(report["teacher_steps"])
    far_ratio = int(report["config"]["teacher"].get("far_steps", 0)) / teacher_steps
    steps = sorted(set(FIELD_STEPS) | {teacher_steps})
    reference_steps = 2 * max(steps)

    tmp, out = run / ".bench.partial", run / "bench"
    _clear_all_but_variants(tmp)
    (tmp / "variants").mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm

    per_res = len(test) * (len(steps) + 1) + 2 + len(chosen)
    bar = tqdm(total=len(chosen) + len(res) * per_res, desc="bench", disable=not progress, leave=False)
    try:
        bundles, skipped, reused = {}, {}, []
        for v in chosen:
            bar.set_postfix_str(f"distilling {v.name}")
            if (same := v.same_as_run(facts)) is not None:
                skipped[v.name] = same
                bar.update(1)
                continue
            settings = _merged(report["config"], variant_overrides(v, facts))
            marker = {"source": report.get("source"), "config": settings, "version": report["version"]}
            folder = tmp / "variants" / v.name
            try:
                stored = _finished_variant(folder, marker)
                if stored is not None:
                    bundles[v.name] = (v, load_bundle(folder / "bundle"), stored)
                    reused.append(v.name)
                    log(f"bench: resumed: variant {v.name} reused from the killed bench's .bench.partial/")
                else:
                    shutil.rmtree(folder, ignore_errors=True)
                    result = distill(field, cameras, load_config(overrides=settings), folder, progress=False,
                                     log=lambda m: None, keep_work=False, reuse_from=[run / "work"],
                                     source=report.get("source"))
                    bundles[v.name] = (v, result.bundle, result.report)
                    for heavy in VARIANT_FOLDERS_DROPPED:      # 12 of a variant's 13 MB on the demo
                        shutil.rmtree(folder / heavy, ignore_errors=True)
                    (folder / VARIANT_MARKER).write_text(json.dumps(marker, sort_keys=True))
            except BadInputError as exc:
                skipped[v.name] = str(exc)
                log(f"bench: variant {v.name} skipped: {exc}")
            bar.update(1)
        for leftover in (tmp / "variants").iterdir():     # a killed bench's unfinished or unchosen variants
            if leftover.name not in bundles:
                shutil.rmtree(leftover, ignore_errors=True)
        default = load_bundle(run / "bundle")
        points, fronts = [], {}
        for w, h in res:
            cams = test.resized(w, h)
            bar.set_postfix_str(f"{w}x{h}: field reference, {reference_steps} steps")
            reference = render_reference(field, cams, reference_steps, progress=lambda: bar.update(1),
                                         far_ratio=far_ratio)
            bar.set_postfix_str(f"{w}x{h}: field at {', '.join(map(str, steps))} steps")
            here = field_points(field, cams, steps, reference, progress=lambda: bar.update(1), far_ratio=far_ratio)
            here[steps.index(teacher_steps)]["label"] += " (the teacher's)"
            entries = []
            if default.plain_rgb is not None:
                plain = plain_bundle(default, default.plain_rgb.astype("float32") / 255.0)
                entries.append(GLEntry("plain texture (no MLP)", "plain-texture", plain, {"bundle_bytes": None}))
            entries.append(GLEntry("default", "bundle", default, {
                "default": True, "bundle_bytes": int(report["bundle_bytes"]), "description": "the run's own bundle"}))
            for name, (v, bundle, rep) in bundles.items():
                entries.append(GLEntry(name, "bundle", bundle, {
                    "bundle_bytes": int(rep["bundle_bytes"]), "description": v.description,
                    "texture_resolution": rep["texture_resolution"], "mesh_faces": rep["mesh_faces"]}))
            bar.set_postfix_str(f"{w}x{h}: {len(entries)} bundles, interleaved")
            here.extend(gl_points(entries, cams, reference, progress=lambda: bar.update(1)))
            bar.update(2 + len(chosen) - len(entries))
            for p in here:
                p.setdefault("default", False)
                p.setdefault("bundle_bytes", None)
                p["resolution"] = [w, h]
                p["reference_steps"] = reference.steps
            fronts[f"{w}x{h}"] = pareto_front(here)
            points.extend(here)
    finally:
        bar.close()
    w, h = max(res, key=lambda r: r[0] * r[1])
    largest = f"{w}x{h}"
    pick = recommend([p for p in points if f"{p['resolution'][0]}x{p['resolution'][1]}" == largest], target)
    result = {"run": str(run.resolve()), "points": points, "pareto": fronts[largest], "pareto_by_resolution": fronts,
              "target_ms": target, "recommended": pick["label"] if pick else None, "skipped": skipped,
              "reused_variants": reused,
              "variants": {v.name: {"description": v.description, "changes": variant_overrides(v, facts)}
                           for v in chosen},
              "machine": _machine(gl_info()), "seconds": time.perf_counter() - t_start}
    from .output import write_outputs

    write_outputs(result, tmp)
    if out.exists():
        shutil.rmtree(out)
    os.replace(tmp, out)
    from .output import add_to_report_html

    add_to_report_html(run, result)
    log(f"bench: {len(points)} points in {result['seconds']:.0f} s; front at {largest}: {', '.join(result['pareto'])}; "
        f"written to {out}")
    return result
