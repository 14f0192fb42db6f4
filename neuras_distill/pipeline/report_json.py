"""The run's ``report.json`` (its keys are the public contract, docs/contract.md), assembled from the stages'
results."""

from __future__ import annotations

import platform
import sys
import time

import numpy as np
import torch

from .. import __version__
from ..bake.bundle import Bundle
from ..geometry.unwrap import atlas_shape
from ..neural.shader_inputs import ShaderInputs
from .stage_results import (
    Backdrop,
    CameraSplit,
    DistilledModel,
    Evaluation,
    GeometryResult,
    TrainingPlan,
    TrainingViews,
)
from .stages.context import RunContext


def device_info(gl_info: dict | None, device: torch.device | str = "cpu") -> dict:
    """What ran each side: ``field`` (the field, the teacher and the held-out field renders), ``training`` (the
    neural texture's optimisation), ``bundle`` (OpenGL's renderer; ``bundle_note`` when a software renderer
    played it on a machine with a GPU), ``requested`` (the resolved ``--device``)."""
    from ..device import describe
    from ..playback.context import software_gl

    compute = describe(device)
    gl = gl_info or {}
    renderer = str(gl.get("renderer", "?"))
    out = {"field": compute, "training": compute,
           "bundle": f"OpenGL: {renderer} ({gl.get('version', '?')})",
           "requested": str(torch.device(device)), "python": sys.version.split()[0], "platform": platform.platform()}
    if torch.cuda.is_available() and software_gl(renderer):
        out["bundle_note"] = ("the bundle was played by a software OpenGL renderer on a machine with a GPU: its "
                              "frame rate is not the GPU's; install the vendor's EGL driver (NVIDIA: "
                              "libnvidia-gl, libegl1) so that EGL picks the GPU")
    return out


def code_commit() -> str | None:
    """The git commit of the package's source (``"<hash>+dirty"`` when tracked files differ from it), or None when
    the package is not a tracked file of a git checkout (an installed wheel)."""
    import subprocess
    from pathlib import Path

    here = Path(__file__).resolve().parent
    try:
        tracked = subprocess.run(["git", "-C", str(here), "ls-files", "--error-unmatch", Path(__file__).name],
                                 capture_output=True, timeout=10)
        head = subprocess.run(["git", "-C", str(here), "rev-parse", "--short=12", "HEAD"],
                              capture_output=True, text=True, timeout=10)
        if tracked.returncode != 0 or head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(here), "diff", "--quiet", "HEAD", "--"],
                               capture_output=True, timeout=30).returncode == 1
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty else "")


def field_summary(ctx: RunContext) -> dict:
    """What the report says of the field: unbounded or not, the far region the teacher marched (its planes, its
    samples per ray, and the share of the teacher's field evaluations spent there), the adapter's notes, and
    the frame its own tool's viewer uses (``viewer_frame``: a field's optional method; None without one)."""
    field, renderer = ctx.field, ctx.volume_renderer
    region = renderer.far_region
    stats = renderer.stats
    total = max(1, stats.get("geometry_points", 0))
    return {"unbounded": bool(getattr(field, "unbounded", False)),
            "far_region": ({"near": region.near, "far": region.far, "pivot": region.pivot,
                            "far_steps": renderer.far_steps,
                            "far_share_of_points": stats.get("far_points", 0) / total}
                           if region is not None else None),
            "notes": list(getattr(field, "notes", []) or []),
            "viewer_frame": _viewer_frame(field)}


def _viewer_frame(field) -> dict | None:
    """``field.viewer_frame()`` (a device wrapper passes the attribute on from the host field), or None."""
    method = getattr(field, "viewer_frame", None)
    return method() if callable(method) else None


def training_stop(plan: TrainingPlan, log: dict) -> dict:
    """Which rule stopped training: {"rule": "configured steps" | "texel rule" | "plateau" | "time budget",
    "steps", "why"} (``plan``: the run's ``TrainingPlan``; ``log``: ``TrainLog.as_dict()``)."""
    steps, stopped = int(log["steps"]), log.get("stopped_by", "steps")
    if stopped == "plateau":
        (step, best) = max(log["held_back"], key=lambda h: h[1])
        return {"rule": "plateau", "steps": steps,
                "why": f"the held-back training pixels stopped improving (best {best:.2f} dB at step {step}; "
                       f"{steps} of the {plan.steps} planned steps ran)"}
    if stopped == "time_budget":
        return {"rule": "time budget", "steps": steps,
                "why": f"the time budget ran out after {log['seconds']:.0f} s, at step {steps} of {plan.steps}"}
    if plan.configured_steps:
        return {"rule": "configured steps", "steps": steps, "why": f"the {steps} configured steps ran"}
    if plan.needed_steps is not None and plan.needed_steps > plan.steps:
        return {"rule": "time budget", "steps": steps,
                "why": f"the {plan.time_budget_s:.0f} s cap affords {plan.steps} of the {plan.needed_steps} steps "
                       "the texel rule asks for"}
    samples = steps * plan.samples_per_step / max(plan.used_texels or 1, 1)
    return {"rule": "texel rule", "steps": steps,
            "why": f"{steps} steps gave every used texel about {samples:.0f} training samples"}


def build_report(ctx: RunContext, views: CameraSplit, geometry: GeometryResult, inputs: ShaderInputs,
                 plan: TrainingPlan, training: TrainingViews, backdrop: Backdrop, distilled: DistilledModel,
                 bundle: Bundle,
                 ev: Evaluation, *, stability: dict | None, source: dict | None, gl_info: dict | None,
                 device: torch.device | str = "cpu") -> dict:
    """``report.json`` without the timing of the whole run and the work area (``pipeline.run`` adds them)."""
    cfg, train, test, mesh = ctx.cfg, views.train, views.test, geometry.mesh
    field_seconds = ev.field_views.seconds
    fps_before = 1.0 / float(np.median(field_seconds))
    fps_after = float(ev.timing["fps"])
    _, tex_res, pages = atlas_shape(mesh.stats)
    skybox = distilled.skybox
    log = distilled.log
    return {
        "version": __version__,
        "commit": code_commit(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "fps_before": fps_before,
        "fps_after": fps_after,
        "speedup": fps_after / fps_before,
        "resolution": [test.width, test.height],
        "device": dict(device_info(gl_info, device), precision=cfg.teacher.precision),
        "psnr": ev.quality["psnr"],
        "ssim": ev.quality["ssim"],
        "lpips": None,
        "lpips_note": "no LPIPS backbone weights available locally (none are downloaded)",
        "parity_psnr": ev.parity,
        "psnr_per_view": ev.quality["psnr_per_view"],
        "ssim_per_view": ev.quality["ssim_per_view"],
        **ev.fidelity,  # flip, psnr_interior / _silhouette / _smooth, hole_fraction (+ _per_view), crops
        "fidelity_seconds": ev.fidelity_seconds,
        "evaluate_seconds": {k: round(v, 3) for k, v in ev.part_seconds.items()},
        "distill_seconds": None,
        "stage_seconds": ctx.clock.seconds,
        "stage_peak_rss_mb": ctx.clock.peak_rss_mb,             # the process's peak when each stage ended
        "mesh_faces": mesh.num_faces,
        "mesh_stats": {k: v for k, v in mesh.stats.items() if isinstance(v, (int, float, str))},
        "texture_resolution": [tex_res, tex_res],           # of one page
        "atlas_pages": pages,
        "feature_dim": cfg.texture.feature_dim,
        "codebook_size": int(bundle.manifest.get("num_codes", cfg.texture.num_codes)),
        "bundle_bytes": int(bundle.nbytes_on_disk()),
        "feature_bytes_vq": int(bundle.feature_nbytes()),
        "feature_bytes_float16": int(bundle.float16_nbytes()),
        "left_out": ctx.decisions.left_out(),
        "decisions": ctx.decisions.to_json(),
        "view_dependence": {"used": inputs.use_viewdir, "measured_spread": inputs.view_spread,
                            "core": inputs.use_viewdir if inputs.core_viewdir is None else inputs.core_viewdir},
        "skybox": ({"used": True, "reason": backdrop.reason, **skybox.layers.to_json(),
                    "num_codes": int(bundle.manifest["skybox"]["num_codes"]),
                    "touched_fraction": log["sky_touched_fraction"]}
                   if skybox is not None else {"used": False, "reason": backdrop.reason}),
        "ablation": ev.ablation,
        "extrapolation": ev.extrapolation,
        "origin": [float(x) for x in training.origin],
        "error_vs_runtime": ev.runtime_points,
        "frame_time_ms": {"field_median": 1000 * float(np.median(field_seconds)),
                          "bundle_median": ev.timing["median_ms"], "bundle_p90": ev.timing.get("p90_ms"),
                          "bundle_gpu_median": ev.timing.get("gpu_median_ms"),
                          "bundle_pipelined": ev.timing.get("pipelined_ms"),
                          "bundle_shading": ev.timing.get("shading")},
        "speedup_pipelined": (1000.0 / ev.timing["pipelined_ms"]) / fps_before if ev.timing.get("pipelined_ms")
        else None,
        "plain_texture": ev.plain,
        "silhouette_blend": ev.silhouette_blend,
        "training_plan": plan.to_json(),
        "training_stop": training_stop(plan, log),
        "stability": stability,
        "train_log": list(log["entries"]),
        "train_summary": {k: v for k, v in log.items() if k != "entries"},
        "views": {"train": len(train), "test": len(test), "train_resolution": [train.width, train.height]},
        "teacher_steps": cfg.teacher.num_steps,
        "field": field_summary(ctx),
        "config": cfg.to_dict(),
        "source": source,
    }
