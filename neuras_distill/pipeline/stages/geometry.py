"""Stage 3: the mesh. Extract the surface (marching cubes or fused depths, cleanup, decimation, culling, a
trial unwrap), choose the atlas side from it, unwrap at that side; then the shader inputs the mesh decides (the
training steps it decides are the plan's: ``stages/plan.py``)."""

from __future__ import annotations

import numpy as np

from ...errors import AtlasTooSmallError
from ...geometry.depth_fusion import FAINT_MIN_WIDTH_PX
from ...geometry.extract import (
    FAINT_SURFACE_OPACITY,
    FUSED_OUTSET_VOXELS,
    SHELL_TEXEL_SCALE,
    Surface,
    extract_surface,
    unwrap_surface,
)
from ...geometry.unwrap import atlas_shape
from ...neural.shader_inputs import ShaderInputs
from .. import choices, rules
from ..cache import digest
from ..stage_results import CameraSplit, GeometryResult, TeacherResult, TrainingPlan
from .context import RunContext, settings


def geometry_stage(ctx: RunContext, views: CameraSplit, teacher: TeacherResult,
                   plan: TrainingPlan) -> tuple[GeometryResult, ShaderInputs]:
    """The unwrapped mesh in the run's local frame (``RunContext.origin``; stored as ``surface``, then
    ``geometry``) with how its atlas side was chosen (from ``plan``'s samples), and the shader inputs it decides.
    Decisions recorded: the fringe shell, the atlas's texels, culled faces, shader inputs."""
    g = ctx.cfg.geometry
    ctx.clock.start("geometry", f"marching cubes at {g.grid_resolution}, decimation to {g.face_budget} faces, "
                                "culling, UV unwrap")
    enclose = choices.fringe_shell(g.enclose_fringe, teacher.opacities, ctx.background, ctx.decisions)
    surface = extract(ctx, views, teacher, enclose)
    auto_side = ctx.cfg.texture.resolution == 0
    side, density = choose_atlas_side(ctx, surface, views, plan) if auto_side else (ctx.cfg.texture.resolution, {})
    weighted = ctx.cfg.texture.view_weighted_texels and surface.layout is None
    weights = rules.view_texel_weights(surface.mesh, ctx.local(views.train)) if weighted else None
    page_size = ctx.cfg.texture.page_size
    paged = page_size < max(side, ctx.cfg.texture.max_resolution if auto_side else side)
    key = digest("geometry", ctx.keys["surface"], side, rules.MIN_TEXEL_YIELD if auto_side else None,
                 *(("at least what the charts need",) if auto_side else ()),
                 *(("view-weighted texels",) if weighted else ()), *(("pages of", page_size) if paged else ()))

    def unwrap_at(at_side: int):
        ctx.log(f"    geometry: UV layout for a {at_side}x{at_side} atlas")
        return unwrap_surface(surface, at_side, unwrap_timeout_s=g.unwrap_timeout_s, face_weights=weights,
                              page_size=page_size)

    def unwrap_at_side() -> GeometryResult:
        mesh = unwrap_at(side)
        if not auto_side:
            return GeometryResult(mesh, density)
        # the side was chosen from the trial unwrap's uv area; many small charts lose more of a small atlas to
        # their padding: unwrap once more at a larger side when too few texels hold surface
        wanted = density["pixels"] / rules.PIXELS_PER_TEXEL ** 2
        used = used_texels(mesh)
        grown = rules.side_for_texels(side, used, wanted, hi=min(ctx.cfg.texture.max_resolution,
                                                                     density.get("budget", side)))
        # never below what its charts need (every chart 4 x 4 texels with its padding): a small training budget
        # (a small tile's) caps the side as a preference, a side too small for the charts does not play
        charts_need = int(np.ceil(np.sqrt(16 * int(mesh.stats.get("uv_charts") or 0)) / 64.0)) * 64
        grown = max(grown, min(charts_need, ctx.cfg.texture.max_resolution))
        if grown == side:
            return GeometryResult(mesh, density)
        regrown = unwrap_at(grown)
        info = dict(density, chosen=grown, texel_yield=used / wanted, regrown_from=side,
                    texel_yield_after=used_texels(regrown) / wanted)
        return GeometryResult(regrown, info)

    result = ctx.cached("geometry", key, unwrap_at_side, GeometryResult.save, GeometryResult.load)
    mesh, density = result.mesh, result.density if auto_side else density
    tex_res, charts = int(mesh.stats["uv_resolution"]), int(mesh.stats.get("uv_charts") or 0)
    need = int(np.ceil(np.sqrt(16 * charts)))            # every chart at least 4x4 texels with its padding
    if tex_res < need:
        raise AtlasTooSmallError(f"a {tex_res}x{tex_res} texture is too small for this mesh: its {charts} UV charts "
                                 f"need at least {need}x{need} texels; raise --texture-resolution (or use 0 for "
                                 "automatic) or lower --face-budget", need)
    choices.atlas_pages(mesh.stats, ctx.decisions)
    if auto_side:
        choices.atlas_side(tex_res, density, ctx.cfg.texture.max_resolution, ctx.decisions)
        if density.get("regrown_from"):
            choices.larger_atlas_for_small_charts(tex_res, charts, density, ctx.decisions)
    if weighted:
        choices.view_weighted_texels(weights, ctx.decisions)
    choices.surface_source(mesh.stats, ctx.decisions)
    choices.unseen_faces(int(mesh.stats.get("culled_faces", 0)), ctx.decisions)
    inputs = choose_shader_inputs(ctx, mesh, enclose)
    ctx.clock.done(key=key, **{k: v for k, v in mesh.stats.items() if isinstance(v, (int, float, str))})
    return result, inputs


def extract(ctx: RunContext, views: CameraSplit, teacher: TeacherResult, enclose: bool) -> Surface:
    """The field's surface (marching cubes, or the teacher's fused depths), cleaned, decimated, culled and
    unwrapped once at a trial side (``geometry.extract.extract_surface``); ``enclose``: around the soft fringe."""
    g = ctx.cfg.geometry
    # the trial unwrap's side does not depend on a fixed atlas side, so runs that differ only in it (the bench's
    # atlas variants) share the stored surface; the final unwrap is at the chosen side
    trial_side = min(1024, ctx.cfg.texture.max_resolution)

    def compute() -> Surface:
        return extract_surface(ctx.local_field, ctx.local(views.train), g, trial_resolution=trial_side,
                               density_level=getattr(ctx.field, "surface_level", None),
                               field_opacity=teacher.opacities if enclose else None,
                               field_depth=(teacher.surface_depths, teacher.fringe_depths, teacher.opacities))

    key = digest("surface", ctx.keys["teacher"], settings(g, ("cull_back_faces",)), trial_side, enclose,
                 "local frame", ctx.origin.tolist(), "fused outset", FUSED_OUTSET_VOXELS,
                 "faint surface", FAINT_SURFACE_OPACITY, FAINT_MIN_WIDTH_PX)
    return ctx.cached("surface", key, compute, Surface.save, Surface.load)


def choose_atlas_side(ctx: RunContext, surface: Surface, views: CameraSplit, plan: TrainingPlan) -> tuple[int, dict]:
    """(atlas side, texel-density figures): the side at which the training views see about one texel per
    ``rules.PIXELS_PER_TEXEL`` pixels of the surface's core, or per ``PIXELS_PER_TEXEL / SHELL_TEXEL_SCALE``
    pixels of its fringe shell (laid out at a quarter of the core's texel density), whichever needs more,
    capped by ``texture.max_resolution`` and by what the training plan's samples can fit
    (``rules.training_budget_resolution``). The shell counts for foggy fields, whose colour sits mostly in
    the fringe: the nerfstudio fixture's core covered 8,378 training pixels and got a 128² atlas."""
    layers = surface.trial.layers()
    hi = ctx.cfg.texture.max_resolution
    train = ctx.local(views.train)
    side, info = rules.texel_density_resolution(layers[0], train, hi=hi)
    if len(layers) > 1:
        shell_side, shell = rules.texel_density_resolution(
            layers[1], train, hi=hi, pixels_per_texel=rules.PIXELS_PER_TEXEL / SHELL_TEXEL_SCALE)
        info = dict(info, shell_pixels=shell["pixels"], shell_uv_area=shell["uv_area"], shell_exact=shell["exact"])
        if shell["exact"] > info["exact"]:
            side, info = shell_side, dict(info, exact=shell["exact"], from_shell=1)
    samples = plan.max_steps * plan.samples_per_step
    budget = rules.training_budget_resolution(samples, info["uv_area"])
    return min(side, budget), dict(info, chosen=min(side, budget), budget=budget, samples=samples)


def used_texels(mesh) -> float:
    """Texels the unwrapped ``mesh``'s charts cover in its atlas (all its pages)."""
    height, width, _ = atlas_shape(mesh.stats)
    return min(1.0, mesh.uv_area()) * height * width


def choose_shader_inputs(ctx: RunContext, mesh, enclose: bool) -> ShaderInputs:
    """What the shader takes besides the features, decided on the mesh (``pipeline.choices``)."""
    cfg, record = ctx.cfg, ctx.decisions
    use_facing = choices.facing_input(mesh, enclose, record)
    use_viewdir, spread = choices.view_dependence(ctx.local_field, mesh, cfg, record, fringe_shell=use_facing)
    core_viewdir = choices.core_view_dependence(ctx.local_field, mesh, cfg, use_viewdir, record)
    reflect, roughness = choices.reflected_view_input(mesh, cfg, use_viewdir, use_facing, record)
    return ShaderInputs(use_viewdir, spread, use_facing, core_viewdir, reflect=reflect,
                        normal_roughness_deg=roughness)
