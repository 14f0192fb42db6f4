"""``distill(field, cameras, config, out)``: the whole pipeline, stage by stage, into one run folder.

Stages (each timed, each with a small manifest under ``stages/<name>/``): cameras -> teacher -> geometry ->
gbuffer -> distill -> bake -> evaluate. The run folder is written in a hidden sibling and moved into place at
the end, so a failed run leaves nothing half-written (``pipeline.rundir``).

Resuming: the expensive results (teacher renders, the training plan, the mesh, the G-buffers, the trained
model, the field's held-out renders) are stored in the run's work area under keys that digest exactly their
inputs (``pipeline.cache``); the same command after a kill reuses every finished one and continues training
from its last checkpoint, and a changed setting recomputes only the stages downstream of it. Each stage
seeds torch and numpy from the run's seed and its own name, so its result does not depend on whether the
stages before it ran or were reused.

Frames: the field and the teacher work in world coordinates. Everything that runs in float32 on the GPU
side (G-buffers, training inputs, the bundle) works relative to the foreground box's centre (``origin``,
float64), so a scene kilometres from its world origin keeps float32 precision; the bundle records the origin.
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..config import DistillConfig, load_config
from ..device import OUT_OF_MEMORY, out_of_memory_message, peak_memory_mb
from ..errors import BadInputError, require
from ..logs import say
from ..render.cameras import Cameras
from . import report as report_mod, stages
from .cache import StageCache
from .report_json import build_report
from .run_outputs import write_run_outputs
from .rundir import RunFolder
from .stages.context import RunContext
from .torchrun import launch_from_env

if TYPE_CHECKING:
    from ..fields.base import Field


@dataclass
class DistillResult:
    report: dict
    out: Path | None
    bundle: object

    def __repr__(self) -> str:
        r = self.report
        return (f"DistillResult(psnr={r['psnr']:.2f} dB, ssim={r['ssim']:.4f}, speedup={r['speedup']:.0f}x, "
                f"out={self.out})")


def distill(field: Field, cameras: Cameras | None = None, config: DistillConfig | dict | None = None,
            out: str | Path | None = None, *, log=None, progress: bool = True, fresh: bool = False,
            keep_work: bool = True, source: dict | None = None, reuse_from=(), device="auto",
            nproc: int = 1, held_out: Cameras | None = None) -> DistillResult:
    """Distill ``field`` into a bundle that OpenGL plays, and measure it against the field.

    Args:
        field: any object following the Field contract (kind, aabb, geometry, radiance).
        cameras: the cameras to train and evaluate on (OpenGL convention); every ``test_every``-th is held
            out. When None: ``field.cameras`` if the field brings them, else the field's ``default_cameras``.
        held_out: the cameras to evaluate on, when the split is given: ``cameras`` are then all trained on
            and none of them is held out (a tile of a tiled scene is scored at the scene's held-out cameras).
        config: a DistillConfig, a dict of overrides, or None for the defaults.
        out: run folder (bundle, report.json, report.md, images). None: nothing is written (and nothing is
            reused). A run killed before it finished leaves ``.<name>.partial`` beside it; the same call
            reuses its finished stages and training checkpoint (``report["resumed"]``).
        log: a ``(line)`` callable for the run's messages; None: ``logging.getLogger("neuras_distill")`` at INFO
            (``neuras_distill.logs``; the command line installs its handler).
        progress: draw one progress display over the run (``pipeline/progress.py``: stage, views, steps, ETA).
        fresh: ignore every stored stage (they are recomputed and stored again).
        keep_work: keep the work area (``<out>/work``: stored stages, G-buffers) after success, for the next
            run into the same folder; False removes it.
        source: where the field came from, stored as ``report["source"]`` (the command line records its
            arguments and working folder, so the run can be repeated or benchmarked from its folder); default:
            the field's class.
        reuse_from: more work areas (``<run>/work`` folders) whose stored stages may be reused (hard-linked)
            when their keys match: the bench distils its variants from the run's teacher, mesh and G-buffers.
        device: where the field, the teacher, the held-out field renders and training compute: ``"auto"``
            (the first GPU when torch sees one, else the CPU), ``"cpu"``, ``"cuda"``, ``"cuda:N"`` or a
            :class:`torch.device`. A field's tensors are moved there in place. The bundle is played by OpenGL.
        nproc: processes that share the teacher's volume rendering (this one and ``nproc - 1`` spawned
            workers, ``neuras_distill.pipeline.parallel``; CPU only); 1: none are spawned. Under torchrun or
            srun (``pipeline/torchrun.py``) every rank calls ``distill`` with the same field, cameras and
            configuration and the ranks share the work across machines instead; ``nproc`` must then be 1.
    Returns:
        DistillResult with ``report`` (the contract keys), ``bundle`` and ``out``; None on the ranks other than
        0 of a torchrun / srun launch (rank 0 writes the run folder).
    Raises:
        BadInputError: for anything the user can fix (message says what and how).
    """
    from ..device import resolve_device
    from ..fields.base import check_field
    from .parallel import check_nproc

    device = resolve_device(device)
    nproc = check_nproc(nproc)
    require(nproc == 1 or device.type == "cpu",
            f"--nproc {nproc} shares volume rendering between CPU processes; on {device} use --nproc 1")
    launch = launch_from_env()
    require(launch is None or nproc == 1,
            f"--nproc {nproc} spawns processes on this machine, but {launch and launch.launcher} already launched "
            f"{launch and launch.world}: leave --nproc out and launch one process per share")
    require(launch is None or device.type == "cpu",
            f"{launch and launch.launcher}: the ranks share the teacher and training as CPU processes; pass "
            f"--device cpu (on {device}, run one process: the GPU does the work of many CPU ranks)")
    if launch is not None and launch.rank != 0:
        log, progress = (lambda msg: None), False        # rank 0 speaks for the run
    log = log or say
    if config is None:
        cfg = DistillConfig().validate()
    elif isinstance(config, dict):
        cfg = load_config(overrides=config)
    else:
        cfg = config.validate()
    check_field(field)
    source = source or {"python": f"{type(field).__module__}.{type(field).__qualname__}"}
    cameras, camera_origin = pick_cameras(field, cameras, cfg, held_out)
    if camera_origin.startswith("generated"):
        log(f"cameras: {camera_origin}")
    stability, cfg = _check_stability(field, cameras, cfg, log)
    torch.manual_seed(cfg.train.seed)
    np.random.seed(cfg.train.seed)

    if launch is not None:
        return _run_launched(launch, out, field, cameras, cfg, log, progress, stability, source, device,
                             camera_origin, fresh, keep_work, reuse_from, held_out)
    with _render_pool(field, nproc) as pool:
        return _run_into(out, field, cameras, cfg, log, progress, stability, source, device, camera_origin,
                         fresh, keep_work, reuse_from, pool, held_out)


def _run_launched(launch, out, field, cameras, cfg, log, progress, stability, source, device, camera_origin,
                  fresh, keep_work, reuse_from, held_out=None) -> DistillResult | None:
    """One rank of a torchrun / srun launch: every rank checks that the others got the same field, cameras,
    configuration and version; rank 0 runs with a pool over the group, the others serve it."""
    from .. import __version__
    from .cache import digest, field_fingerprint
    from .parallel import RenderPool
    from .torchrun import agree, join_group, serve

    join_group(launch, str(device))
    places = agree(launch, {"field": field_fingerprint(field),
                            "cameras": digest(cameras.to_json(), None if held_out is None else held_out.to_json()),
                           "configuration": digest(json.dumps(dataclasses.asdict(cfg), sort_keys=True, default=str)),
                           "version": __version__})
    if launch.rank != 0:
        serve(field, launch)
        return None
    pool = RenderPool.joined(launch, places)
    log(f"{launch.launcher}: {launch.world} ranks on {pool.nodes()} nodes share the teacher and training")
    with pool:
        return _run_into(out, field, cameras, cfg, log, progress, stability, source, device, camera_origin,
                         fresh, keep_work, reuse_from, pool, held_out)


def _render_pool(field, nproc: int):
    """A :class:`~neuras_distill.pipeline.parallel.RenderPool` for ``nproc`` > 1, else a context holding None."""
    import contextlib

    if nproc == 1:
        return contextlib.nullcontext(None)
    from .parallel import RenderPool

    return RenderPool(field, nproc)


def _run_into(out, field, cameras, cfg, log, progress, stability, source, device, camera_origin, fresh, keep_work,
              reuse_from, pool, held_out=None) -> DistillResult:
    """:func:`_run` without a folder (``out`` None) or into a :class:`RunFolder` (resumable)."""
    if out is None:
        return _run(field, cameras, cfg, None, log, progress, stability, source=source, device=device,
                    camera_origin=camera_origin, pool=pool, held_out=held_out)
    folder = RunFolder(out, keep_work=keep_work)
    with folder as tmp:
        if folder.resumed_folder:
            log(f"found an unfinished run in {tmp.name}: reusing its finished stages")
        for path in folder.removed_leftovers:
            log(f"removed {path.name} (left by a killed run of an earlier version)")
        cache = StageCache(folder.work, [folder.previous_work, *map(Path, reuse_from)], fresh=fresh, log=log)
        try:
            result = _run(field, cameras, cfg, tmp, log, progress, stability, cache=cache, keep_work=keep_work,
                          source=source, device=device, camera_origin=camera_origin, pool=pool, held_out=held_out)
        except BaseException:
            if folder.work.is_dir() and any(folder.work.glob("*/*/done.json")):
                log(f"finished stages are kept in {tmp}; the same command reuses them (--fresh ignores them)")
            raise
    result.out = folder.out
    log(f"run folder: {folder.out}")
    return result


def _check_stability(field: Field, cameras: Cameras, cfg: DistillConfig, log) -> tuple[dict, DistillConfig]:
    """``neuras-distill check`` on the field before anything is rendered (``stability/probe.py``): a refused
    probe stops the run with its reason; adaptations raise the configuration's settings (never lower them)
    where they are at their defaults; a setting the user (or a preset) chose is kept and the recommendation
    reported. Returns (the report's JSON with ``applied`` and ``not_applied`` ({key: [current, recommended]}),
    the configuration the run uses: a validated copy with the raised settings; ``cfg`` itself is not changed,
    so a second run with the same object starts from the same settings)."""
    from ..stability.probe import probe_field

    report = probe_field(field, cameras, num_steps=cfg.teacher.num_steps,
                         grid_resolution=cfg.geometry.grid_resolution)
    require(report.verdict != "refused", f"the field cannot be distilled: {report.reason()}")
    defaults = DistillConfig()
    applied, kept = {}, {}
    for key, value in report.adaptations.items():
        section, name = key.split(".", 1)
        part = getattr(cfg, section)
        old = getattr(part, name)
        if value == old or (not isinstance(value, str) and value <= old):
            continue
        if old != getattr(getattr(defaults, section), name):
            kept[key] = [old, type(old)(value)]
            continue
        cfg = replace(cfg, **{section: replace(part, **{name: type(old)(value)})})
        applied[key] = [old, type(old)(value)]
    cfg = cfg.validate()
    result = report.to_json()
    result.update(applied=applied, not_applied=kept)
    log(f"stability check: {report.verdict}"
        + (f"; raised {', '.join(f'{k} {a} -> {b}' for k, (a, b) in applied.items())}" if applied else "")
        + (f"; kept as configured {', '.join(f'{k} {a} (recommended {b})' for k, (a, b) in kept.items())}"
           if kept else "") + f" ({report.seconds:.1f} s)")
    return result, cfg


def pick_cameras(field: Field, cameras, cfg: DistillConfig, held_out=None) -> tuple[Cameras, str]:
    """(cameras, where they came from: ``"given"``, ``"the field's own"`` or ``"generated: ..."`` with the first
    line of the field's ``default_cameras`` docstring; ``report["views"]["cameras"]``)."""
    origin = "given"
    if cameras is None:
        cameras = getattr(field, "cameras", None)
        origin = "the field's own"
    if cameras is None:
        make = getattr(field, "default_cameras", None)
        require(callable(make), "no cameras given and the field brings none; pass cameras "
                                "(e.g. nd.Cameras.from_transforms('transforms.json'))")
        import inspect

        extra = ({"held_out_every": cfg.cameras.test_every}
                 if "held_out_every" in inspect.signature(make).parameters else {})
        cameras = make(cfg.cameras.num_views, cfg.cameras.width, cfg.cameras.height, **extra)
        doc = " ".join((inspect.getdoc(make) or "").split("\n\n")[0].split())
        origin = f"generated by {type(field).__name__}.default_cameras" + (f": {doc}" if doc else "")
    require(isinstance(cameras, Cameras), f"cameras must be an nd.Cameras, got {type(cameras).__name__}")
    if held_out is not None:
        require(isinstance(held_out, Cameras) and len(held_out) >= 1 and len(cameras) >= 1,
                "held_out must be an nd.Cameras of at least one camera, beside at least one training camera")
        return cameras, origin
    require(len(cameras) >= 2, f"need at least 2 cameras (some to train on, some held out), got {len(cameras)}")
    return cameras, origin


#: The default device of :func:`_run`: the host.
_HOST = torch.device("cpu")


def _run(field: Field, cameras: Cameras, cfg: DistillConfig, root: Path | None, log, progress: bool,
         stability: dict | None = None, cache: StageCache | None = None, keep_work: bool = True,
         source: dict | None = None, device: torch.device = _HOST,
         camera_origin: str = "given", pool=None, held_out: Cameras | None = None) -> DistillResult:
    """The seven stages in order (``pipeline.stages``), then the report."""
    from ..playback.context import gl_info

    t_start = time.perf_counter()
    ctx = RunContext(field, cfg, root, cache, log, progress, device=device, pool=pool)
    try:
        views = stages.split_cameras(ctx, cameras, held_out)
        teacher, teacher_views = stages.render_teacher(ctx, views)
        plan = stages.plan_limits(ctx, views, teacher_views)              # the training plan: its limits,
        ctx.display.expect("evaluate", plan.eval_seconds)
        geometry, inputs = stages.geometry_stage(ctx, views, teacher_views, plan)
        plan = stages.fix_steps(ctx, plan, stages.used_texels(geometry.mesh))  # its steps (then its clock)
        ctx.display.expect("distill", plan.steps / plan.steps_per_second if plan.steps_per_second
                           else plan.time_budget_s)
        training, backdrop = stages.gbuffer_stage(ctx, views, teacher_views, geometry, inputs)
        distilled = stages.distill_stage(ctx, teacher_views, plan, training, inputs, backdrop)
        if pool is not None:        # the last stage the other processes share: they leave while this one goes on
            pool.close()
        bundle = stages.bake_stage(ctx, views, teacher_views, training, distilled, backdrop)
        evaluation = stages.evaluation_stage(ctx, views, teacher, training, distilled, backdrop, bundle)
    except OUT_OF_MEMORY as exc:                    # a GPU that ran out of memory mid-run: one line, exit 2
        raise BadInputError(out_of_memory_message(device, ctx.clock.current)) from exc
    finally:
        ctx.display.close()

    rep = build_report(ctx, views, geometry, inputs, plan, training, backdrop, distilled, bundle, evaluation,
                       stability=stability, source=source, gl_info=gl_info(), device=device)
    rep["views"]["cameras"] = camera_origin
    rep["processes"] = pool.nproc if pool is not None else 1
    if pool is not None:
        rep["ranks"] = pool.ranks()
    rep["scene_aabb"] = [[float(v) for v in row] for row in torch.as_tensor(field.aabb).double().reshape(2, 3)]
    rep.update(peak_memory_mb(device))
    rep["resumed"] = {"stages": list(cache.reused) if cache is not None else [],
                      "from_step": distilled.log.get("resumed_from_step")}
    if cache is not None:
        cache.prune(ctx.keys)
        rep["work_area"] = {"path": "work", "kept": keep_work, "bytes": cache.nbytes(), "keys": ctx.keys}
        if rep["resumed"]["stages"] or rep["resumed"]["from_step"]:
            log("resumed: reused " + (", ".join(rep["resumed"]["stages"]) or "no stored stage")
                + (f"; training continued from step {rep['resumed']['from_step']}" if rep["resumed"]["from_step"]
                   else ""))
    rep["distill_seconds"] = time.perf_counter() - t_start
    if root is not None:
        write_run_outputs(root, rep, evaluation.field_views.images, evaluation.bundle_images,
                                     evaluation.extra_views, evaluation.flip_maps)
    log(report_mod.summary_table(rep))
    return DistillResult(report=rep, out=root, bundle=bundle)
