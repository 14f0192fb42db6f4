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

import json
import platform
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .. import __version__
from ..config import DistillConfig, load_config
from ..errors import BadInputError, require
from ..render.cameras import Cameras
from . import decisions, evaluate, report as report_mod
from .cache import StageCache, digest, field_fingerprint
from .rundir import RunFolder
from .stage_results import FieldViews, GeometryResult, TeacherResult, TrainedModel, load_gbuffer, save_gbuffer


@dataclass
class DistillResult:
    report: dict
    out: Path | None
    bundle: object

    def __repr__(self) -> str:
        r = self.report
        return (f"DistillResult(psnr={r['psnr']:.2f} dB, ssim={r['ssim']:.4f}, speedup={r['speedup']:.0f}x, "
                f"out={self.out})")


class _Stages:
    """Times stages, seeds each one (:func:`_seed_stage`) and writes their manifests."""

    def __init__(self, root: Path | None, log, seed: int = 0):
        self.root, self.log, self.seconds, self._t0 = root, log, {}, None
        self.index, self.seed = 0, seed

    def start(self, name: str, what: str) -> None:
        self.index += 1
        self.log(f"[{self.index}/7] {name}: {what}")
        self._name, self._t0 = name, time.perf_counter()
        _seed_stage(self.seed, name)

    def done(self, **info) -> float:
        seconds = time.perf_counter() - self._t0
        self.seconds[self._name] = round(seconds, 3)
        if self.root is not None:
            folder = self.root / "stages" / self._name
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "manifest.json").write_text(json.dumps(
                {"stage": self._name, "version": __version__, "seconds": seconds, **info}, indent=2, default=str))
        return seconds


def _seed_stage(seed: int, stage: str) -> None:
    """Seed torch and numpy from the run's seed and the stage's name."""
    import zlib

    s = (int(seed) * 1_000_003 + zlib.crc32(stage.encode())) % 2**31
    torch.manual_seed(s)
    np.random.seed(s)


def _cached(cache: StageCache | None, stage: str, key: str, compute, save, load):
    """``cache.cached`` when the run has a work area, else just ``compute()``."""
    if cache is None:
        return compute()
    return cache.cached(stage, key, compute, save, load)


def _settings(section, drop: tuple = ()) -> dict:
    """A config section as a dict for cache keys, without the settings that do not change results."""
    from dataclasses import asdict

    return {k: v for k, v in asdict(section).items() if k not in drop}


def _device_info(gl_info: dict | None) -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    field_side = f"CPU: {cpu} ({torch.get_num_threads()} threads), torch {torch.__version__}"
    if torch.cuda.is_available():
        field_side = f"GPU: {torch.cuda.get_device_name(0)}"
    gl = gl_info or {}
    return {"field": field_side, "bundle": f"OpenGL: {gl.get('renderer', '?')} ({gl.get('version', '?')})",
            "python": sys.version.split()[0], "platform": platform.platform()}


def _resolve_skyboxes(field, cfg: DistillConfig, gbuffer, left_out: list) -> tuple[bool, str]:
    """(use skyboxes, reason) from the configuration and measurements (see decisions.py)."""
    mode = cfg.skybox.mode
    if mode == "off":
        left_out.append({"component": "skyboxes", "reason": "turned off by configuration"})
        return False, "off"
    if mode == "on":
        return True, "turned on by configuration"
    uncovered = float(1.0 - gbuffer.coverage.mean())
    if uncovered == 0.0:
        reason = "every training ray ends on the foreground mesh"
        left_out.append({"component": "skyboxes", "reason": reason})
        return False, reason
    constant_bg, bg_reason = decisions.background_is_constant(field)
    if constant_bg:
        left_out.append({"component": "skyboxes", "reason": bg_reason})
        return False, bg_reason
    return True, f"{100 * uncovered:.1f}% of training pixels miss the mesh and {bg_reason}"


def _training_budget(cfg: DistillConfig, teacher_seconds: float, train: Cameras, test: Cameras, field) -> dict:
    """The training plan's limits, known once the teacher has run: ``time_budget_s`` (configured, or a share
    of the run's volume rendering, ``decisions.training_time_budget``), the measured ``steps_per_second`` and
    ``max_steps`` (configured steps, or what the budget affords). Steps are fixed later (:func:`_plan_steps`)."""
    tr = cfg.train
    samples_per_step = tr.batch_patches * tr.patch ** 2
    # held-out views, plus the error-vs-runtime curve on one view (a 2x reference and each step count) and
    # the lane-shifted views of scenes that define them
    curve = (2 * cfg.teacher.num_steps + sum(cfg.eval.runtime_steps) + cfg.teacher.num_steps) / cfg.teacher.num_steps
    shifts = 2 * len(getattr(field, "lane_shifts", None) or [])
    eval_pixels = int((len(test) + curve + shifts) * test.width * test.height)
    budget = tr.time_budget_s or decisions.training_time_budget(teacher_seconds, len(train) * train.width * train.height,
                                                                 eval_pixels)
    plan = {"time_budget_s": float(budget), "samples_per_step": samples_per_step, "steps_per_second": None,
            "configured_steps": tr.steps or None}
    if tr.steps:                   # configured steps run to the end unless a time budget is configured too
        plan.update(max_steps=tr.steps, time_budget_s=tr.time_budget_s or None)
    else:
        t = cfg.texture
        speed = decisions.probe_training_speed(t.feature_dim, t.hidden, t.num_layers, tr.batch_patches, tr.patch)
        plan.update(steps_per_second=speed, max_steps=max(decisions.MIN_TRAIN_STEPS, int(budget * speed)))
    return plan


def _plan_steps(plan: dict, mesh, tex_res: int, left_out: list) -> None:
    """Fix ``plan["steps"]``: configured, or enough for ``decisions.TARGET_SAMPLES_PER_TEXEL`` samples per used
    texel of the ``tex_res`` atlas within ``max_steps``; the choice is reported in ``left_out``."""
    used = min(1.0, mesh.uv_area()) * tex_res ** 2
    steps, needed = decisions.training_steps(used, plan["samples_per_step"], plan["max_steps"])
    if plan["configured_steps"]:
        steps = plan["configured_steps"]
    plan.update(steps=int(steps), needed_steps=int(needed), used_texels=int(used))
    if plan["configured_steps"]:
        why = (f"{steps} steps as configured ({needed} would give {decisions.TARGET_SAMPLES_PER_TEXEL} samples per "
               "used texel)")
    elif needed > plan["max_steps"]:
        why = (f"{steps} steps: the {plan['time_budget_s']:.0f} s budget (at {plan['steps_per_second']:.0f} "
               f"steps/s) affords fewer than the "
               f"{needed} that give {decisions.TARGET_SAMPLES_PER_TEXEL} samples to each of {int(used)} used texels")
    else:
        why = (f"{steps} steps give {decisions.TARGET_SAMPLES_PER_TEXEL} samples to each of {int(used)} used "
               f"texels (at least {decisions.MIN_TRAIN_STEPS}); the time budget would allow {plan['max_steps']}")
    plan["reason"] = why
    left_out.append({"component": "training beyond the atlas's needs", "reason": why})


def _resolve_silhouette_blend(mode: str, fringe_pixels: float, train: Cameras, test: Cameras,
                              left_out: list) -> bool:
    """Whether the bundle plays with the soft-silhouette pass: when the field's fringe, ``fringe_pixels`` wide in
    the training views, is at least ``decisions.SILHOUETTE_BLEND_MIN_PIXELS`` wide at the held-out (playing)
    resolution (``mode`` "auto"; "on" / "off" force it); otherwise left out with the reason."""
    if mode != "auto":
        if mode == "off":
            left_out.append({"component": "soft-silhouette pass", "reason": "turned off by configuration"})
        return mode == "on"
    width = fringe_pixels * float(test.width) / float(train.width)
    if width >= decisions.SILHOUETTE_BLEND_MIN_PIXELS:
        return True
    left_out.append({"component": "soft-silhouette pass",
                     "reason": f"the field's edges are {width:.1f} pixels wide at {test.width}x{test.height} "
                               f"(< {decisions.SILHOUETTE_BLEND_MIN_PIXELS:g}): the mesh's hard edges match them"})
    return False


def _resolve_fringe(field, cfg: DistillConfig, opacity: np.ndarray, left_out: list) -> bool:
    """Whether the mesh should enclose the field's soft fringe (see ``geometry.marching``): when the fringe is
    at least ``decisions.FRINGE_MIN_PIXELS`` wide in the training views and the background is one constant
    colour (over it, a partly opaque fringe pixel is one colour per view and angle, which the texture learns
    with the facing input; over skyboxes it is not)."""
    mode = cfg.geometry.enclose_fringe
    if mode != "auto":
        return mode == "on"
    width = decisions.fringe_width_pixels(opacity)
    if width < decisions.FRINGE_MIN_PIXELS:
        left_out.append({"component": "soft-fringe shell",
                         "reason": f"the field's fringe is {width:.1f} training pixels wide (< "
                                   f"{decisions.FRINGE_MIN_PIXELS:g}): the mesh stays at the surface level"})
        return False
    constant, _ = decisions.background_is_constant(field)
    if not constant:
        left_out.append({"component": "soft-fringe shell",
                         "reason": f"the field's fringe is {width:.1f} training pixels wide, but the background "
                                   "is not one colour (skyboxes): the mesh stays at the surface level"})
    return constant


def _resolve_facing(mesh, enclose: bool, left_out: list) -> bool:
    """The facing cosine |n . d| as a shader input when the mesh has a shell enclosing a soft fringe (its
    grazing pixels fade with the angle; see ``neural/shader.py``); otherwise left out, with the reason."""
    if enclose and mesh.core_faces is not None:
        return True
    if enclose:
        left_out.append({"component": "facing input",
                         "reason": "the mesh at the field's surface level already covers its opaque pixels"})
    return False


def _resolve_view_dependence(field, mesh, cfg: DistillConfig, left_out: list,
                             fringe_shell: bool = False) -> tuple[bool, float | None]:
    """(use the view direction, measured spread). A mesh moved out to a soft fringe's shell keeps it whatever
    the field's own radiance does: a ray crossing the fringe averages colours along its path, so the colour at
    a shell point changes with the direction (gradient ball: held-out interior 24.3 dB without it)."""
    mode = cfg.texture.view_dependence
    if mode == "on" or (mode == "auto" and fringe_shell):
        return True, None
    if mode == "off":
        left_out.append({"component": "view direction", "reason": "turned off by configuration"})
        return False, None
    spread = decisions.measure_view_dependence(field, mesh, seed=cfg.train.seed)
    if spread < cfg.texture.view_threshold:
        left_out.append({"component": "view direction",
                         "reason": f"the field's colour barely changes with view direction (mean spread "
                                   f"{spread:.4f} < {cfg.texture.view_threshold}); the shader has no view input"})
        return False, spread
    return True, spread


def _resolve_core_view_dependence(field, mesh, cfg: DistillConfig, use_viewdir: bool,
                                  left_out: list) -> bool | None:
    """Whether the core's shader of a two-layer mesh takes the view direction (None: as ``use_viewdir``).

    A core at the level the field's colour comes from (``geometry.colour_level``, ``mc_colour_level_used``)
    sees no parallax through the fringe, so it needs the direction only when the field's own colour changes
    with it (measured on the core, ``decisions.measure_view_dependence``); the shell keeps it (its fringe
    pixels average colours along the ray). Without it the gradient ball's held-out core interior scored 41.3
    against 39.3 dB (``NeuralTextureModel``, ``core_viewdir``)."""
    if (not use_viewdir or mesh.core_faces is None or cfg.texture.view_dependence != "auto"
            or not mesh.stats.get("mc_colour_level_used")):
        return None
    spread = decisions.measure_view_dependence(field, mesh.layers()[0], seed=cfg.train.seed)
    if spread >= cfg.texture.view_threshold:
        return None
    left_out.append({"component": "view direction of the core's shader",
                     "reason": f"the core sits where the field's colour comes from and that colour barely changes "
                               f"with the view (mean spread {spread:.4f} < {cfg.texture.view_threshold}); only "
                               "the fringe shell's shader takes the direction"})
    return False


def distill(field, cameras: Cameras | None = None, config: DistillConfig | dict | None = None,
            out: str | Path | None = None, *, log=None, progress: bool = True, fresh: bool = False,
            keep_work: bool = True, source: dict | None = None, reuse_from=()) -> DistillResult:
    """Distill ``field`` into a bundle that OpenGL plays, and measure it against the field.

    Args:
        field: any object following the Field contract (kind, aabb, geometry, radiance).
        cameras: the cameras to train and evaluate on (OpenGL convention); every ``test_every``-th is held
            out. When None: ``field.cameras`` if the field brings them, else the field's ``default_cameras``.
        config: a DistillConfig, a dict of overrides, or None for the defaults.
        out: run folder (bundle, report.json, report.md, images). None: nothing is written (and nothing is
            reused). A run killed before it finished leaves ``.<name>.partial`` beside it; the same call
            reuses its finished stages and training checkpoint (``report["resumed"]``).
        fresh: ignore every stored stage (they are recomputed and stored again).
        keep_work: keep the work area (``<out>/work``: stored stages, G-buffers) after success, for the next
            run into the same folder; False removes it.
        source: where the field came from, stored as ``report["source"]`` (the command line records its
            arguments and working folder, so the run can be repeated or benchmarked from its folder); default:
            the field's class.
        reuse_from: more work areas (``<run>/work`` folders) whose stored stages may be reused (hard-linked)
            when their keys match: the bench distils its variants from the run's teacher, mesh and G-buffers.
    Returns:
        DistillResult with ``report`` (the contract keys), ``bundle`` and ``out``.
    Raises:
        BadInputError: for anything the user can fix (message says what and how).
    """
    from ..fields.base import check_field

    log = log or (lambda msg: print(msg, file=sys.stderr, flush=True))
    if config is None:
        cfg = DistillConfig().validate()
    elif isinstance(config, dict):
        cfg = load_config(overrides=config)
    else:
        cfg = config.validate()
    check_field(field)
    source = source or {"python": f"{type(field).__module__}.{type(field).__qualname__}"}
    cameras = _pick_cameras(field, cameras, cfg)
    stability = _check_stability(field, cameras, cfg, log)
    torch.manual_seed(cfg.train.seed)
    np.random.seed(cfg.train.seed)

    if out is None:
        return _run(field, cameras, cfg, None, log, progress, stability, source=source)
    folder = RunFolder(out, keep_work=keep_work)
    with folder as tmp:
        if folder.resumed_folder:
            log(f"found an unfinished run in {tmp.name}: reusing its finished stages")
        for path in folder.removed_leftovers:
            log(f"removed {path.name} (left by a killed run of an earlier version)")
        cache = StageCache(folder.work, [folder.previous_work, *map(Path, reuse_from)], fresh=fresh, log=log)
        try:
            result = _run(field, cameras, cfg, tmp, log, progress, stability, cache=cache, keep_work=keep_work,
                          source=source)
        except BaseException:
            if folder.work.is_dir() and any(folder.work.glob("*/*/done.json")):
                log(f"finished stages are kept in {tmp}; the same command reuses them (--fresh ignores them)")
            raise
    result.out = folder.out
    log(f"run folder: {folder.out}")
    return result


def _check_stability(field, cameras: Cameras, cfg: DistillConfig, log) -> dict:
    """``neuras-distill check`` on the field before anything is rendered (``stability/probe.py``): a refused
    probe stops the run with its reason; adaptations raise the configuration's settings (never lower them)
    where they are at their defaults; a setting the user (or a preset) chose is kept and the recommendation
    reported. Returns the report's JSON with ``applied`` and ``not_applied`` ({key: [current, recommended]})."""
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
        setattr(part, name, type(old)(value))
        applied[key] = [old, type(old)(value)]
    result = report.to_json()
    result.update(applied=applied, not_applied=kept)
    log(f"stability check: {report.verdict}"
        + (f"; raised {', '.join(f'{k} {a} -> {b}' for k, (a, b) in applied.items())}" if applied else "")
        + (f"; kept as configured {', '.join(f'{k} {a} (recommended {b})' for k, (a, b) in kept.items())}"
           if kept else "") + f" ({report.seconds:.1f} s)")
    return result


def _pick_cameras(field, cameras, cfg: DistillConfig) -> Cameras:
    if cameras is None:
        cameras = getattr(field, "cameras", None)
    if cameras is None:
        make = getattr(field, "default_cameras", None)
        require(callable(make), "no cameras given and the field brings none; pass cameras "
                                "(e.g. nd.Cameras.from_transforms('transforms.json'))")
        import inspect

        extra = ({"held_out_every": cfg.cameras.test_every}
                 if "held_out_every" in inspect.signature(make).parameters else {})
        cameras = make(cfg.cameras.num_views, cfg.cameras.width, cfg.cameras.height, **extra)
    require(isinstance(cameras, Cameras), f"cameras must be an nd.Cameras, got {type(cameras).__name__}")
    require(len(cameras) >= 2, f"need at least 2 cameras (some to train on, some held out), got {len(cameras)}")
    return cameras


def _run(field, cameras: Cameras, cfg: DistillConfig, root: Path | None, log, progress: bool,
         stability: dict | None = None, cache: StageCache | None = None, keep_work: bool = True,
         source: dict | None = None) -> DistillResult:
    from ..bake.bundle import bake
    from ..neural.model import NeuralTextureModel, view_inputs
    from ..neural.train import fit
    from ..geometry.extract import Surface, extract_surface, unwrap_surface
    from ..playback.context import gl_info
    from ..geometry.mesh import MeshData
    from ..neural.skybox import SkyboxModel, plan_layers
    from ..playback.projection import shift_cameras
    from ..playback.rasterize import rasterize_gbuffer
    from ..playback.renderer import BundleRenderer
    from ..playback.shaders import VERTEX_SHADER
    from ..render.volume import VolumeRenderer

    from ..neural.train_checkpoint import TrainCheckpoint

    t_start = time.perf_counter()
    stages = _Stages(root, log, cfg.train.seed)
    left_out: list[dict] = []
    keys: dict[str, str] = {}
    fingerprint = field_fingerprint(field)

    # 1. cameras ------------------------------------------------------------------------------------
    stages.start("cameras", f"{len(cameras)} cameras, holding out every {cfg.cameras.test_every}th")
    train_full, test_full = cameras.split(cfg.cameras.test_every)
    train = train_full.resized(cfg.teacher.train_width)
    test = test_full.resized(cfg.eval.width) if cfg.eval.width else test_full    # 0: the cameras' own size
    if root is not None:
        (root / "cameras.json").write_text(json.dumps({"train": train.to_json(), "test": test.to_json()}))
    sky_layers = None
    if cfg.skybox.mode != "off":            # planned (and the user's distances checked) before any rendering
        sky_layers = plan_layers(field.aabb, cameras.centers.double().numpy(), num_layers=cfg.skybox.layers,
                                 near=cfg.skybox.near or None, far=cfg.skybox.far or None,
                                 resolution=cfg.skybox.resolution)
    stages.done(train=len(train), test=len(test), train_size=[train.width, train.height],
                test_size=[test.width, test.height])

    # 2. teacher ------------------------------------------------------------------------------------
    stages.start("teacher", f"volume-rendering {len(train)} training views at {train.width}x{train.height}, "
                            f"{cfg.teacher.num_steps} steps/ray")
    teacher = VolumeRenderer(field, num_steps=cfg.teacher.num_steps)

    def render_teacher() -> TeacherResult:
        t0 = time.perf_counter()
        views = evaluate.render_field_views(teacher, train, _progress_printer(log, "teacher", progress), depths=True)
        return TeacherResult(np.stack(views.images).astype(np.float32), np.stack(views.opacities),
                             np.stack(views.surface_depths), np.stack(views.fringe_depths),
                             seconds=time.perf_counter() - t0)

    keys["teacher"] = digest("teacher", fingerprint, train.to_json(), _settings(cfg.teacher))
    teacher_out = _cached(cache, "teacher", keys["teacher"], render_teacher, TeacherResult.save, TeacherResult.load)
    targets, train_opacity = teacher_out.images, teacher_out.opacities
    require(bool(np.isfinite(targets).all()), "the field renders NaN or Inf colours; check its parameters")
    stages.done(views=len(train), key=keys["teacher"], render_seconds=teacher_out.seconds)
    keys["plan"] = digest("plan", keys["teacher"], test.to_json(), _settings(cfg.train, ("checkpoint_every_s",)),
                          _settings(cfg.texture), _settings(cfg.eval))
    plan = _cached(cache, "plan", keys["plan"],
                   lambda: _training_budget(cfg, teacher_out.seconds, train, test, field),
                   lambda p, folder: (folder / "plan.json").write_text(json.dumps(p)),
                   lambda folder: json.loads((folder / "plan.json").read_text()))

    # 3. geometry -----------------------------------------------------------------------------------
    stages.start("geometry", f"marching cubes at {cfg.geometry.grid_resolution}, decimation to "
                             f"{cfg.geometry.face_budget} faces, culling, UV unwrap")
    density: dict = {}

    def by_texel_density(unwrapped):
        # the core sets the density (a fringe shell covers the same pixels at a quarter of its texel density)
        side, info = decisions.texel_density_resolution(unwrapped.layers()[0], train, hi=cfg.texture.max_resolution)
        samples = plan["max_steps"] * plan["samples_per_step"]
        budget = decisions.training_budget_resolution(samples, info["uv_area"])
        density.update(info, chosen=min(side, budget), budget=budget, samples=samples)
        return min(side, budget)

    auto_res = cfg.texture.resolution == 0
    enclose = _resolve_fringe(field, cfg, train_opacity, left_out)

    # the trial unwrap's side does not depend on a fixed atlas side, so runs that differ only in it (the bench's
    # atlas variants) share the stored surface; the final unwrap is at the chosen side
    trial_side = min(1024, cfg.texture.max_resolution)

    def extract() -> Surface:
        return extract_surface(field, train, grid_resolution=cfg.geometry.grid_resolution,
                               face_budget=cfg.geometry.face_budget, trial_resolution=trial_side,
                               unwrap_timeout_s=cfg.geometry.unwrap_timeout_s, cull_unseen=cfg.geometry.cull_unseen,
                               density_level=getattr(field, "surface_level", None),
                               cull_margin_deg=cfg.geometry.cull_margin_deg,
                               field_opacity=train_opacity if enclose else None,
                               field_depth=(teacher_out.surface_depths, teacher_out.fringe_depths, train_opacity),
                               core_level=cfg.geometry.core_level, from_depths=cfg.geometry.surface == "depths")

    # the surface does not depend on the training plan; the atlas side (chosen from it when automatic) only
    # changes the final unwrap
    keys["surface"] = digest("surface", keys["teacher"], _settings(cfg.geometry, ("cull_back_faces",)),
                             trial_side, enclose)
    surface = _cached(cache, "surface", keys["surface"], extract, Surface.save, Surface.load)
    side = by_texel_density(surface.trial) if auto_res else cfg.texture.resolution
    keys["geometry"] = digest("geometry", keys["surface"], side)
    geometry = _cached(cache, "geometry", keys["geometry"],
                       lambda: GeometryResult(unwrap_surface(surface, side, unwrap_timeout_s=cfg.geometry.unwrap_timeout_s),
                                              dict(density)),
                       GeometryResult.save, GeometryResult.load)
    mesh = geometry.mesh
    tex_res = int(mesh.stats["uv_resolution"])
    charts = int(mesh.stats.get("uv_charts") or 0)
    need = int(np.ceil(np.sqrt(16 * charts)))            # every chart at least 4x4 texels with its padding
    require(tex_res >= need, f"a {tex_res}x{tex_res} texture is too small for this mesh: its {charts} UV charts "
                             f"need at least {need}x{need} texels; raise --texture-resolution (or use 0 for "
                             f"automatic) or lower --face-budget")
    if auto_res:
        capped = density["exact"] > cfg.texture.max_resolution
        ppt = decisions.PIXELS_PER_TEXEL
        left_out.append({"component": "texels beyond the training views' detail",
                         "reason": f"atlas {tex_res}x{tex_res} chosen from texel density: the training views see "
                                   f"{density['pixels']:.0f} pixels of surface on {100 * density['uv_area']:.1f}% "
                                   f"of the atlas, one texel per {ppt:g}x{ppt:g} pixels at {density['exact']:.0f}"
                                   + (f" (capped at max_resolution {cfg.texture.max_resolution})" if capped else "")
                                   + (f"; limited to {density['budget']} by the training budget ({density['samples']} "
                                      f"samples, {decisions.SAMPLES_PER_TEXEL} per used texel)"
                                      if density["budget"] < density["exact"] else "")})
    culled = int(mesh.stats.get("culled_faces", 0))
    if culled:
        left_out.append({"component": "unseen faces",
                         "reason": f"{culled} faces seen by no training camera were culled before unwrapping "
                                   "(they get no texels)"})
    use_facing = _resolve_facing(mesh, enclose, left_out)
    use_viewdir, view_spread = _resolve_view_dependence(field, mesh, cfg, left_out, fringe_shell=use_facing)
    core_viewdir = _resolve_core_view_dependence(field, mesh, cfg, use_viewdir, left_out)
    _plan_steps(plan, mesh, tex_res, left_out)
    stages.done(key=keys["geometry"], **{k: v for k, v in mesh.stats.items() if isinstance(v, (int, float, str))})

    # 4. gbuffer ------------------------------------------------------------------------------------
    stages.start("gbuffer", f"rasterizing {mesh.num_faces} faces for {len(train)} views (OpenGL)")
    aabb64 = np.asarray(torch.as_tensor(field.aabb).double().reshape(2, 3).cpu().numpy())
    origin = 0.5 * (aabb64[0] + aabb64[1])            # float64: GL and training work relative to it
    local_mesh = MeshData((mesh.vertices.astype(np.float64) - origin).astype(np.float32), mesh.faces, mesh.uvs,
                          mesh.stats, core_faces=mesh.core_faces)
    keys["gbuffer"] = digest("gbuffer", keys["geometry"], train.to_json(), cfg.geometry.cull_back_faces)
    gbuffer = _cached(cache, "gbuffer", keys["gbuffer"],
                      lambda: rasterize_gbuffer(local_mesh, shift_cameras(train, origin),
                                                cull_back_faces=cfg.geometry.cull_back_faces),
                      save_gbuffer, load_gbuffer)
    dirs = view_inputs(np.stack([train.rays(i)[1].numpy() for i in range(len(train))]), gbuffer.face_id,
                       gbuffer.normal, use_facing, local_mesh.core_faces)
    use_skybox, sky_reason = _resolve_skyboxes(field, cfg, gbuffer, left_out)
    skybox = None
    sb = cfg.skybox
    if use_skybox:
        skybox = SkyboxModel(sky_layers, feature_dim=sb.feature_dim, num_codes=sb.num_codes, hidden=sb.hidden)
        sky_origins = sky_layers.relative(train.centers.double().numpy()).numpy()
    missed = ~gbuffer.coverage
    if use_skybox or (missed.any() and not decisions.background_is_constant(field)[0]):
        # the clear colour: what the missed training pixels show on average (skyboxes draw over it)
        bg = torch.as_tensor(targets[missed].mean(axis=0) if missed.any() else np.zeros(3), dtype=torch.float32)
    else:
        bg = decisions.background_color(field)
    stages.done(key=keys["gbuffer"], coverage=float(gbuffer.coverage.mean()), skyboxes=use_skybox,
                skybox_reason=sky_reason)

    # 5. distill ------------------------------------------------------------------------------------
    t = cfg.texture
    stages.start("distill", f"{tex_res}^2 x {t.feature_dim} feature atlas, "
                            + (f"{t.num_codes} codes, " if t.quantize else "no VQ, ")
                            + f"MLP {t.num_layers}x{t.hidden}{'' if use_viewdir else ' (no view input)'}, "
                            f"{plan['steps']} steps" + (f" (at most {plan['time_budget_s']:.0f} s)"
                                                        if plan["time_budget_s"] else ""))
    model = NeuralTextureModel(tex_res, tex_res, feature_dim=t.feature_dim, num_codes=t.num_codes,
                               hidden=t.hidden, num_layers=t.num_layers, use_viewdir=use_viewdir,
                               use_facing=use_facing, mesh_layers=len(local_mesh.layers()),
                               core_viewdir=core_viewdir, use_vq=t.quantize)
    keys["distill"] = digest("distill", keys["gbuffer"], keys["plan"], plan["steps"], plan["time_budget_s"],
                             _settings(cfg.texture), _settings(cfg.train, ("checkpoint_every_s",)),
                             _settings(cfg.skybox), use_viewdir, use_facing, core_viewdir, use_skybox,
                             sky_layers.to_json() if use_skybox else None, bg)
    checkpoint = (TrainCheckpoint(cache.work / "checkpoints" / f"distill-{keys['distill']}.pt", keys["distill"],
                                  every_s=cfg.train.checkpoint_every_s, log=log) if cache is not None else None)

    def train_model() -> TrainedModel:
        train_log = fit(model, gbuffer.uv, gbuffer.coverage, dirs, targets, steps=plan["steps"],
                        lr=cfg.train.lr, batch_patches=cfg.train.batch_patches, patch=cfg.train.patch,
                        ssim_weight=cfg.train.ssim_weight, vq_warmup=cfg.train.vq_warmup,
                        time_budget_s=plan["time_budget_s"],
                        progress=progress, seed=cfg.train.seed, skybox=skybox,
                        origins=sky_origins if skybox is not None else None, checkpoint=checkpoint)
        if train_log.resumed_from_step:
            log(f"distill: continued from the checkpoint at step {train_log.resumed_from_step}")
        return TrainedModel.of(model, skybox, train_log.as_dict())

    trained = _cached(cache, "distill", keys["distill"], train_model, TrainedModel.save, TrainedModel.load)
    trained.load_into(model, skybox)
    if checkpoint is not None:
        checkpoint.remove()
    train_summary = {k: v for k, v in trained.log.items() if k != "entries"}
    train_history = list(trained.log["entries"])
    stages.done(key=keys["distill"], **train_summary)

    # 6. bake ---------------------------------------------------------------------------------------
    stages.start("bake", "quantized features -> textures, MLP -> GLSL")
    bundle = bake(model, local_mesh, background_color=bg.tolist(), vertex_shader=VERTEX_SHADER,
                  extra_manifest={"left_out": left_out, "view_dependence": use_viewdir,
                                  "cull_back_faces": cfg.geometry.cull_back_faces,
                                  "silhouette_blend": _resolve_silhouette_blend(
                                      cfg.texture.soft_silhouettes, decisions.fringe_width_pixels(train_opacity),
                                      train, test, left_out)},
                  skybox=skybox, origin=origin)
    codes_total = t.num_codes
    codes_kept = int(bundle.manifest.get("num_codes", codes_total))
    if codes_kept < codes_total:
        left_out.append({"component": "unused codes",
                         "reason": f"{codes_total - codes_kept} of {codes_total} codebook entries are used by no "
                                   "texel and were dropped"})
    bundle.manifest["left_out"] = left_out
    # the plain RGB texture (the glTF export's base colour, the report's baseline) travels in the bundle
    from ..bake.plain_texture import plain_texture_rgb8

    bundle.plain_rgb = plain_texture_rgb8(model, bundle.mesh, gbuffer.uv, gbuffer.coverage, dirs)
    if root is not None:
        bundle.save(root / "bundle")
    stages.done(num_codes=codes_kept)

    # 7. evaluate -----------------------------------------------------------------------------------
    stages.start("evaluate", f"{len(test)} held-out views at {test.width}x{test.height}: field vs bundle")
    def render_held_out() -> FieldViews:
        views = evaluate.render_field_views(teacher, test, _progress_printer(log, "field (held-out)", progress))
        return FieldViews(views.images, views.opacities, views.seconds)

    keys["field_views"] = digest("field_views", fingerprint, test.to_json(), _settings(cfg.teacher))
    held_out = _cached(cache, "field_views", keys["field_views"], render_held_out, FieldViews.save, FieldViews.load)
    field_images, field_opacities, field_seconds = held_out.images, held_out.opacities, held_out.seconds
    player = BundleRenderer(bundle)
    bundle_images = [player.render(test, i) for i in range(len(test))]
    quality = evaluate.compare(bundle_images, field_images)
    parity = evaluate.gl_torch_parity(model, local_mesh, shift_cameras(test, origin), bundle_images[0], bg.numpy(),
                                      lambda m, c: rasterize_gbuffer(m, c, cull_back_faces=cfg.geometry.cull_back_faces),
                                      skybox=skybox, world_cameras=test, silhouette_blend=player.silhouette_blend)
    t_fid = time.perf_counter()
    coverages = evaluate.bundle_coverage(
        lambda c: rasterize_gbuffer(local_mesh, c, cull_back_faces=cfg.geometry.cull_back_faces),
        shift_cameras(test, origin))
    fid, flip_maps = evaluate.fidelity(bundle_images, field_images, field_opacities, coverages)
    fid_seconds = time.perf_counter() - t_fid
    ablation = None
    if skybox is not None and sb.ablation:
        no_sky = evaluate.compare([player.render(test, i, skybox=False) for i in range(len(test))], field_images)
        ablation = {"psnr_with_skyboxes": quality["psnr"], "psnr_without_skyboxes": no_sky["psnr"],
                    "drop_db": quality["psnr"] - no_sky["psnr"],
                    "how": "the same bundle played without its skybox pass; pixels the mesh misses get the mean "
                           "colour of the training pixels it misses"}
    timing = player.time_frames(test, warmup=5, frames=cfg.eval.fps_frames)
    plain = evaluate.plain_texture_baseline(model, bundle, gbuffer, dirs, test, field_images, bundle_images,
                                            coverages, cfg.eval.fps_frames)
    points = evaluate.error_vs_runtime(lambda s: VolumeRenderer(field, num_steps=s), test,
                                       2 * cfg.teacher.num_steps, cfg.eval.runtime_steps,
                                       cfg.teacher.num_steps, player)
    fps_before = 1.0 / float(np.median(field_seconds))
    fps_after = float(timing["fps"])
    extrapolation, extra_views = _lane_shift_views(field, teacher, player, test)
    stages.done(psnr=quality["psnr"], ssim=quality["ssim"], parity_psnr=parity, flip=fid["flip"],
                hole_fraction=fid["hole_fraction"], fidelity_seconds=fid_seconds)

    float16_bytes = int(bundle.float16_nbytes())
    vq_bytes = int(bundle.feature_nbytes())
    rep = {
        "version": __version__,
        "fps_before": fps_before,
        "fps_after": fps_after,
        "speedup": fps_after / fps_before,
        "resolution": [test.width, test.height],
        "device": _device_info(gl_info()),
        "psnr": quality["psnr"],
        "ssim": quality["ssim"],
        "lpips": None,
        "lpips_note": "no LPIPS backbone weights available locally (none are downloaded)",
        "parity_psnr": parity,
        "psnr_per_view": quality["psnr_per_view"],
        "ssim_per_view": quality["ssim_per_view"],
        **fid,     # flip, psnr_interior, psnr_silhouette, hole_fraction (+ _per_view), silhouette_band_px, crops
        "fidelity_seconds": fid_seconds,
        "distill_seconds": time.perf_counter() - t_start,
        "stage_seconds": stages.seconds,
        "mesh_faces": mesh.num_faces,
        "mesh_stats": {k: v for k, v in mesh.stats.items() if isinstance(v, (int, float, str))},
        "texture_resolution": [tex_res, tex_res],
        "feature_dim": t.feature_dim,
        "codebook_size": codes_kept,
        "bundle_bytes": int(bundle.nbytes_on_disk()),
        "feature_bytes_vq": vq_bytes,
        "feature_bytes_float16": float16_bytes,
        "left_out": left_out,
        "view_dependence": {"used": use_viewdir, "measured_spread": view_spread,
                            "core": use_viewdir if core_viewdir is None else core_viewdir},
        "skybox": ({"used": True, "reason": sky_reason, **skybox.layers.to_json(),
                    "num_codes": int(bundle.manifest["skybox"]["num_codes"]),
                    "touched_fraction": trained.log["sky_touched_fraction"]}
                   if skybox is not None else {"used": False, "reason": sky_reason}),
        "ablation": ablation,
        "extrapolation": extrapolation,
        "origin": [float(x) for x in origin],
        "error_vs_runtime": points,
        "frame_time_ms": {"field_median": 1000 * float(np.median(field_seconds)),
                          "bundle_median": timing["median_ms"], "bundle_p90": timing.get("p90_ms")},
        "plain_texture": plain,
        "silhouette_blend": player.silhouette_blend,
        "training_plan": plan,
        "stability": stability,
        "train_log": train_history,
        "train_summary": train_summary,
        "views": {"train": len(train), "test": len(test),
                  "train_resolution": [train.width, train.height]},
        "teacher_steps": cfg.teacher.num_steps,
        "config": cfg.to_dict(),
        "source": source,
    }
    rep["resumed"] = {"stages": list(cache.reused) if cache is not None else [],
                      "from_step": trained.log.get("resumed_from_step")}
    if cache is not None:
        cache.prune(keys)
        rep["work_area"] = {"path": "work", "kept": keep_work, "bytes": cache.nbytes(), "keys": keys}
        if rep["resumed"]["stages"] or rep["resumed"]["from_step"]:
            log("resumed: reused " + (", ".join(rep["resumed"]["stages"]) or "no stored stage")
                + (f"; training continued from step {rep['resumed']['from_step']}" if rep["resumed"]["from_step"]
                   else ""))
    rep["distill_seconds"] = time.perf_counter() - t_start
    if root is not None:
        report_mod.write_run_outputs(root, rep, field_images, bundle_images, extra_views, flip_maps)
    log(report_mod.summary_table(rep))
    return DistillResult(report=rep, out=root, bundle=bundle)


def _lane_shift_views(field, teacher, player, test: Cameras, views: int = 2) -> tuple[dict | None, dict]:
    """Extrapolation as the paper evaluates it, for fields that name lane shifts (``field.lane_shifts``, metres):
    the first ``views`` held-out cameras moved sideways by each shift, field vs bundle.
    Returns ({"+2 m": {"psnr", "ssim"}, ...} or None, {image name: [(field, bundle), ...]})."""
    shifts = getattr(field, "lane_shifts", None)
    if not shifts:
        return None, {}
    sub = test[list(range(min(views, len(test))))]
    results, images = {}, {}
    for shift in shifts:
        cams = sub.lane_shifted(float(shift))
        field_images, _ = evaluate.render_field_timed(teacher, cams)
        bundle_images = [player.render(cams, i) for i in range(len(cams))]
        q = evaluate.compare(bundle_images, field_images)
        results[f"{float(shift):+g} m"] = {"psnr": q["psnr"], "ssim": q["ssim"]}
        images[f"lane_{float(shift):+g}m"] = list(zip(field_images, bundle_images))
    return results, images


def _progress_printer(log, label: str, enabled: bool):
    if not enabled:
        return None
    state = {"t0": time.perf_counter()}

    def show(done: int, total: int) -> None:
        elapsed = time.perf_counter() - state["t0"]
        if done == total or done == 1 or done % max(1, total // 5) == 0:
            log(f"    {label}: {done}/{total} views ({elapsed:.1f} s)")

    return show
