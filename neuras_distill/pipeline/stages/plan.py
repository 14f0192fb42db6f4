"""The training plan, its only writer: how long training runs and why.

Its life, in ``pipeline.run._run``'s order:

1. :func:`plan_limits`, after the teacher (stored as ``plan``): the held-out evaluation's estimated seconds,
   training's time cap (``rules.training_cap_s``), the measured steps per second and the most steps the cap
   affords;
2. :func:`fix_steps`, after the geometry: the steps for the atlas's used texels, recorded as a decision;
3. :func:`training_seconds` and :func:`plateau_stop`, when training starts: the cap again from the run's
   clock, and the plateau rule.

``TrainingPlan`` is frozen; each step returns a changed copy (``dataclasses.replace``).
"""

from __future__ import annotations

from dataclasses import replace

from ...neural.convergence import PlateauStop
from .. import choices, rules
from ..cache import digest
from ..stage_results import CameraSplit, TeacherResult, TrainingPlan
from .context import RunContext, settings


def plan_limits(ctx: RunContext, views: CameraSplit, teacher: TeacherResult) -> TrainingPlan:
    """The plan's limits, known once the teacher has run (stored as ``plan``): the held-out evaluation's
    estimated seconds, training's time cap (``rules.training_cap_s``), the measured steps per second and the
    most steps the cap affords (configured steps: those). Steps are fixed after the geometry (:func:`fix_steps`)."""
    key = digest("plan", ctx.keys["teacher"], views.test.to_json(), settings(ctx.cfg.train, ("checkpoint_every_s",)),
                 settings(ctx.cfg.texture), settings(ctx.cfg.eval), rules.TRAIN_CAP_S)
    return ctx.cached("plan", key, lambda: _limits(ctx, teacher.seconds, views), TrainingPlan.save, TrainingPlan.load)


def _limits(ctx: RunContext, teacher_seconds: float, views: CameraSplit) -> TrainingPlan:
    cfg, train, test = ctx.cfg, views.train, views.test
    tr = cfg.train
    samples_per_step = tr.batch_patches * tr.patch ** 2
    # held-out views, plus the error-vs-runtime curve on one view (a 2x reference and each step count) and
    # the lane-shifted views of scenes that define them
    curve = (2 * cfg.teacher.num_steps + sum(cfg.eval.runtime_steps) + cfg.teacher.num_steps) / cfg.teacher.num_steps
    shifts = 2 * len(getattr(ctx.field, "lane_shifts", None) or [])
    eval_pixels = int((len(test) + curve + shifts) * test.width * test.height)
    eval_seconds = rules.evaluation_seconds(teacher_seconds, len(train) * train.width * train.height, eval_pixels)
    cap = rules.training_cap_s(tr.time_budget_s, tr.run_budget_s, ctx.clock.elapsed(), eval_seconds)
    if tr.steps:                   # configured steps run to the end unless a time budget is configured too
        return TrainingPlan(time_budget_s=cap, samples_per_step=samples_per_step, steps_per_second=None,
                            configured_steps=tr.steps, max_steps=tr.steps, eval_seconds=eval_seconds)
    cap = cap or rules.TRAIN_CAP_S
    speed = rules.probe_training_speed(cfg.texture, tr, device=ctx.device)
    return TrainingPlan(time_budget_s=float(cap), samples_per_step=samples_per_step, steps_per_second=speed,
                        configured_steps=None, max_steps=max(rules.MIN_TRAIN_STEPS, int(cap * speed)),
                        eval_seconds=eval_seconds)


def fix_steps(ctx: RunContext, plan: TrainingPlan, used_texels: float) -> TrainingPlan:
    """The plan with its ``steps`` fixed: configured, or enough for ``rules.TARGET_SAMPLES_PER_TEXEL`` samples
    per used texel of the atlas (``used_texels``) within ``max_steps``; the choice is recorded as a decision."""
    steps, needed = rules.training_steps(used_texels, plan.samples_per_step, plan.max_steps)
    if plan.configured_steps:
        steps = plan.configured_steps
    why = choices.training_steps(plan, int(steps), int(needed), used_texels, ctx.decisions)
    return replace(plan, steps=int(steps), needed_steps=int(needed), used_texels=int(used_texels), reason=why)


def training_seconds(ctx: RunContext, plan: TrainingPlan) -> float | None:
    """Training's time cap when it starts: the plan's, or less when the run's budget (``train.run_budget_s``)
    has less left once the evaluation's estimate is kept free (``rules.training_cap_s``)."""
    return rules.training_cap_s(plan.time_budget_s, ctx.cfg.train.run_budget_s, ctx.clock.elapsed(),
                                plan.eval_seconds or 0.0)


def plateau_stop(ctx: RunContext, plan: TrainingPlan) -> PlateauStop | None:
    """The plateau rule of an automatic plan trained in one process (``rules.HOLD_BACK_EVERY`` and the
    ``PLATEAU_*`` figures); None for configured steps and for ``--nproc`` (the ranks would have to agree)."""
    if plan.configured_steps or ctx.pool is not None:
        return None
    return PlateauStop(hold_back_every=rules.HOLD_BACK_EVERY,
                       check_every=max(25, (plan.steps or 0) // rules.PLATEAU_CHECKS),
                       patience=rules.PLATEAU_PATIENCE, min_gain_db=rules.PLATEAU_MIN_GAIN_DB,
                       min_progress=rules.PLATEAU_MIN_PROGRESS, seed=ctx.cfg.train.seed)
