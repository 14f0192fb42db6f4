"""What a run keeps and what it leaves out, as records: each rule here measures (or reads the configuration)
and returns its choice, recording a :class:`Decision` (component, kept, reason, measured) in the run's
:class:`Decisions`. The report renders them: ``report.json["left_out"]`` lists the components left out with
their reasons (the contract), ``report.json["decisions"]`` every decision with what was measured.

The measurements and thresholds themselves live in ``pipeline.rules``; this module turns them into choices.
"""

from __future__ import annotations

from dataclasses import dataclass, field as dataclass_field
from typing import TYPE_CHECKING

import numpy as np

from ..config import DistillConfig
from . import rules

if TYPE_CHECKING:
    from ..fields.base import Field


@dataclass(frozen=True)
class Decision:
    """One choice of the run: ``component`` kept or left out, why, and the figures it rests on."""

    component: str
    kept: bool
    reason: str
    measured: dict = dataclass_field(default_factory=dict)

    def to_json(self) -> dict:
        return {"component": self.component, "kept": self.kept, "reason": self.reason, "measured": self.measured}


class Decisions:
    """The run's decisions in the order they were taken."""

    def __init__(self) -> None:
        self.items: list[Decision] = []

    def keep(self, component: str, reason: str, **measured) -> None:
        self.items.append(Decision(component, True, reason, measured))

    def leave_out(self, component: str, reason: str, **measured) -> None:
        self.items.append(Decision(component, False, reason, measured))

    def left_out(self) -> list[dict]:
        """The contract's ``left_out``: [{"component", "reason"}] of what was left out, in order."""
        return [{"component": d.component, "reason": d.reason} for d in self.items if not d.kept]

    def to_json(self) -> list[dict]:
        return [d.to_json() for d in self.items]


class Background:
    """What rays that miss the foreground see, measured once per run: ``constant`` (bool) and ``reason``
    (``rules.background_is_constant``), and the field's constant ``colour`` ((3,) float32 tensor)."""

    def __init__(self, field: Field) -> None:
        self.constant, self.reason = rules.background_is_constant(field)
        self.colour = rules.background_color(field)


def skyboxes(mode: str, coverage: np.ndarray, background: Background, record: Decisions) -> tuple[bool, str]:
    """(use skyboxes, reason): ``mode`` "on"/"off" as configured; "auto" uses them when training rays miss the
    mesh (``coverage``: (N, H, W) bool, the G-buffers') and the background is not one constant colour."""
    if mode == "off":
        record.leave_out("skyboxes", "turned off by configuration")
        return False, "off"
    if mode == "on":
        record.keep("skyboxes", "turned on by configuration")
        return True, "turned on by configuration"
    uncovered = float(1.0 - coverage.mean())
    if uncovered == 0.0:
        reason = "every training ray ends on the foreground mesh"
        record.leave_out("skyboxes", reason, uncovered_fraction=0.0)
        return False, reason
    if background.constant:
        record.leave_out("skyboxes", background.reason, uncovered_fraction=uncovered)
        return False, background.reason
    reason = f"{100 * uncovered:.1f}% of training pixels miss the mesh and {background.reason}"
    record.keep("skyboxes", reason, uncovered_fraction=uncovered)
    return True, reason


def skybox_layers(share_below: float, record: Decisions) -> int:
    """The skyboxes' layer count when ``skybox.layers`` is 0: ``rules.SKY_LAYERS[1]`` when ``share_below`` (of
    their training pixels looking below the horizon, ``rules.below_horizon_share``) reaches
    ``rules.SKY_GROUND_SHARE``, else ``rules.SKY_LAYERS[0]``."""
    usual, fine = rules.SKY_LAYERS
    measured = {"below_horizon_share": float(share_below)}
    if share_below >= rules.SKY_GROUND_SHARE:
        record.keep("finer skybox depth layers",
                    f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon (at least "
                    f"{100 * rules.SKY_GROUND_SHARE:.0f}%): ground beyond the mesh, whose distance changes across "
                    f"the view; {fine} layers instead of {usual}", layers=fine, **measured)
        return fine
    record.leave_out("finer skybox depth layers",
                     f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon (under "
                     f"{100 * rules.SKY_GROUND_SHARE:.0f}%): {usual} layers hold a sky; {fine} would cost frame time "
                     "(the street: 17% more for 0.01 dB)", layers=usual, **measured)
    return usual


def skybox_codes(share_below: float, record: Decisions) -> int:
    """The skyboxes' codebook size when ``skybox.num_codes`` is 0: ``rules.SKY_CODES[1]`` when ``share_below``
    of their training pixels look below the horizon (at least ``rules.SKY_GROUND_SHARE``), else
    ``rules.SKY_CODES[0]``."""
    usual, more = rules.SKY_CODES
    if share_below >= rules.SKY_GROUND_SHARE:
        record.keep("a larger skybox codebook",
                    f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon: a ground to "
                    f"the horizon is a texture, not a gradient; {more} codes instead of {usual}", codes=more,
                    below_horizon_share=float(share_below))
        return more
    record.leave_out("a larger skybox codebook",
                     f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon: {usual} codes "
                     f"hold a sky; {more} would cost k-means time and bundle size", codes=usual,
                     below_horizon_share=float(share_below))
    return usual


def skybox_ground(share_below: float, hit_share: float | None, heights: np.ndarray, record: Decisions,
                  **measured) -> bool:
    """Whether skyboxes that hold ground lie on it (``neural.skybox.SkyboxGround``): when ``share_below`` of their
    training pixels look below the horizon (at least ``rules.SKY_GROUND_SHARE``) and some of the probed ones reach
    the field's ground: ``heights`` ((L,), ``rules.ground_heights``) is empty when no layer's ring held
    ``rules.GROUND_MIN_HITS`` hits. ``hit_share``: the share of probed rays that reached it (None: the field has
    no far region to probe)."""
    name = "skyboxes on the ground"
    measured = {"below_horizon_share": float(share_below), "ground_hit_share": hit_share, **measured}
    if share_below < rules.SKY_GROUND_SHARE:
        record.leave_out(name, f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon "
                         f"(under {100 * rules.SKY_GROUND_SHARE:.0f}%): their cubes hold a sky", **measured)
        return False
    if hit_share is None:
        record.leave_out(name, "the field has no far region to find a ground in: the cube layers paint what lies "
                         "below the horizon", **measured)
        return False
    if heights.size == 0:
        record.leave_out(name, f"{100 * hit_share:.0f}% of the probed rays that look down reach opacity 0.5 in the "
                         f"field, fewer than {rules.GROUND_MIN_HITS} around any layer: haze, not a ground; the cube "
                         "layers paint it", **measured)
        return False
    record.keep(name, f"{100 * share_below:.0f}% of the pixels the skyboxes learn look below the horizon and "
                f"{100 * hit_share:.0f}% of those probed reach the field's ground: each layer is cut by a floor at "
                f"the median height of the hits around it ({', '.join(f'{h:.3g}' for h in heights)} along the "
                "cameras' up), so the ground beyond the mesh is painted where it lies instead of on the cubes' walls",
                heights=[float(h) for h in heights], **measured)
    return True


def sky_training_pixels(surface_depths: np.ndarray, fringe_depths: np.ndarray, coverage: np.ndarray,
                        origins: np.ndarray, dirs: np.ndarray, aabb, record: Decisions,
                        opacities: np.ndarray | None = None, seen_through=None) -> np.ndarray:
    """(N, H, W) bool: the uncovered training pixels the skyboxes learn from: all but the near misses
    (``rules.near_miss_pixels``: the field shows a surface, or the fringe of one beside the mesh, inside its
    foreground box that the mesh missed). ``surface_depths``, ``fringe_depths`` (N, H, W): where the field's
    opacity reaches 0.5 and the fringe level. ``origins`` (N, 3), ``dirs`` (N, H, W, 3): the training rays.
    Leaving them out is recorded with their share of the pixels. With ``opacities`` (N, H, W), the field's opacity
    inside its box, what the skyboxes still take over inside the box is recorded too: the share of their pixels
    whose box content is at least ``rules.SKY_INSIDE_BOX_OPACITY`` opaque (content the mesh missed that they
    paint from far away, where it slides against its neighbours as the camera moves). ``seen_through``, when
    given, maps the (N, H, W) bool near misses by their fringe alone (the field under 0.5 opacity inside the box)
    to those whose whole ray reaches 0.5 beyond the box (``rules.SEE_THROUGH_PROBE_RAYS``): they show mostly what
    lies behind, and the skyboxes learn them."""
    near = rules.near_miss_pixels(surface_depths, fringe_depths, coverage, origins, dirs, aabb)
    given_back = 0
    if seen_through is not None:
        behind = seen_through(near & ~(np.asarray(surface_depths) > 0))
        given_back = int(behind.sum())
        near = near & ~behind
        record.keep("skybox training behind soft edges",
                    f"{given_back} training pixels beside the mesh are under 0.5 opacity inside the foreground box "
                    "and reach it beyond: they show mostly what lies behind (the ground past the box's floor, the "
                    "background through a soft rim), so the skyboxes learn them", seen_through_pixels=given_back)
    uncovered = ~coverage
    if opacities is not None and uncovered.any():
        learnt = uncovered & ~near
        inside = learnt & (np.asarray(opacities) >= rules.SKY_INSIDE_BOX_OPACITY)
        taken = float(inside.sum() / max(int(learnt.sum()), 1))
        record.keep("skybox pixels inside the box",
                    f"{100 * taken:.2f}% of the pixels the skyboxes learn ({100 * inside.mean():.2f}% of all training "
                    f"pixels) show content inside the foreground box at least "
                    f"{100 * rules.SKY_INSIDE_BOX_OPACITY:.0f}% opaque that the mesh missed: the skyboxes paint it "
                    "from far away", sky_inside_box_fraction=taken, sky_inside_box_pixels=int(inside.sum()))
    share = float(near.sum() / max(int(uncovered.sum()), 1))
    if near.any():
        record.leave_out("skybox training on near misses",
                         f"{100 * share:.1f}% of the pixels the mesh misses show a surface, or a soft edge beside "
                         "the mesh, inside the foreground box (parts thinner than the mesh resolves); trained into "
                         "the skyboxes they would paint it over the sky seen from other views", near_miss_fraction=share,
                         near_miss_pixels=int(near.sum()))
    return uncovered & ~near


def silhouette_blend(mode: str, fringe_pixels: float, train, test, record: Decisions) -> bool:
    """Whether the bundle plays with the soft-silhouette pass: when the field's fringe, ``fringe_pixels`` wide in
    the training views, is at least ``rules.SILHOUETTE_BLEND_MIN_PIXELS`` wide at the held-out (playing)
    resolution (``mode`` "auto"; "on" / "off" force it); otherwise left out with the reason."""
    if mode != "auto":
        if mode == "off":
            record.leave_out("soft-silhouette pass", "turned off by configuration")
        else:
            record.keep("soft-silhouette pass", "turned on by configuration")
        return mode == "on"
    width = fringe_pixels * float(test.width) / float(train.width)
    if width >= rules.SILHOUETTE_BLEND_MIN_PIXELS:
        record.keep("soft-silhouette pass", f"the field's edges are {width:.1f} pixels wide at "
                                            f"{test.width}x{test.height}", edge_pixels=width)
        return True
    record.leave_out("soft-silhouette pass",
                     f"the field's edges are {width:.1f} pixels wide at {test.width}x{test.height} "
                     f"(< {rules.SILHOUETTE_BLEND_MIN_PIXELS:g}): the mesh's hard edges match them",
                     edge_pixels=width)
    return False


def fringe_shell(mode: str, opacity: np.ndarray, background: Background, record: Decisions) -> bool:
    """Whether the mesh should enclose the field's soft fringe (see ``geometry.marching``): when the fringe is
    at least ``rules.FRINGE_MIN_PIXELS`` wide in training views ``rules.FRINGE_REFERENCE_WIDTH`` wide
    (scaled with the views' width; ``opacity``: (N, H, W) teacher opacities) and the background is one constant
    colour (over it, a partly opaque fringe pixel is one colour per view and angle, which the texture learns with
    the facing input; over skyboxes it is not)."""
    if mode != "auto":
        return mode == "on"
    width = rules.fringe_width_pixels(opacity)
    view_width = int(np.asarray(opacity).shape[-1])
    minimum = rules.FRINGE_MIN_PIXELS * view_width / rules.FRINGE_REFERENCE_WIDTH
    if width < minimum:
        record.leave_out("soft-fringe shell",
                         f"the field's fringe is {width:.1f} training pixels wide (< {minimum:.3g} in views "
                         f"{view_width} wide): the mesh stays at the surface level", fringe_pixels=width,
                         view_width=view_width)
        return False
    if not background.constant:
        record.leave_out("soft-fringe shell",
                         f"the field's fringe is {width:.1f} training pixels wide, but the background is not one "
                         "colour (skyboxes): the mesh stays at the surface level", fringe_pixels=width)
        return False
    record.keep("soft-fringe shell", f"the field's fringe is {width:.1f} training pixels wide", fringe_pixels=width)
    return True


def coarse_level(factor: int, plan, record: Decisions) -> int:
    """The coarse feature level's factor (``texture.coarse_factor``; 1: none) for a training ``plan``
    (``TrainingPlan``, steps fixed): kept when training gives each used texel fewer samples than
    ``rules.TARGET_SAMPLES_PER_TEXEL`` (flat surfaces then converge in the coarse level), left out when it gives
    them all (each texel converges on its own, and the level costs a fifth to a half more per step on a CPU)."""
    if factor <= 1:
        record.leave_out("coarse feature level", "turned off by configuration (texture.coarse_factor 1)")
        return 1
    if not plan.used_texels or not plan.steps:
        record.keep("coarse feature level", f"a level {factor} times coarser under the atlas")
        return int(factor)
    per_texel = plan.steps * plan.samples_per_step / plan.used_texels
    measured = dict(samples_per_texel=per_texel, used_texels=plan.used_texels)
    if per_texel >= rules.TARGET_SAMPLES_PER_TEXEL:
        record.leave_out("coarse feature level", f"training gives each of the {plan.used_texels} used texels "
                         f"{per_texel:.0f} samples (at least {rules.TARGET_SAMPLES_PER_TEXEL}): each converges on "
                         "its own", **measured)
        return 1
    record.keep("coarse feature level", f"training gives each of the {plan.used_texels} used texels {per_texel:.0f} "
                f"samples (fewer than {rules.TARGET_SAMPLES_PER_TEXEL}): flat surfaces converge in a level "
                f"{factor} times coarser under the atlas", factor=int(factor), **measured)
    return int(factor)


def facing_input(mesh, enclose: bool, record: Decisions) -> bool:
    """The facing cosine |n . d| as a shader input when the mesh has a shell enclosing a soft fringe (its
    grazing pixels fade with the angle; see ``neural/shader.py``); otherwise left out, with the reason."""
    if enclose and mesh.core_faces is not None:
        record.keep("facing input", "the mesh has a shell enclosing the field's soft fringe")
        return True
    if enclose:
        record.leave_out("facing input", "the mesh at the field's surface level already covers its opaque pixels")
    return False


def extra_views(mode: str, inside: np.ndarray, fringe_shell: bool, train: int, fraction: float,
                record: Decisions) -> int:
    """How many extra training views to add around the training cameras (``render/extra_views.py``). "auto":
    ``fraction`` of the ``train`` views when no camera centre lies inside the field's box (``inside``: (N,) bool;
    an object seen from outside) and the mesh will get a soft-fringe shell (``fringe_shell``, judged by
    :func:`fringe_shell` on a sample of the training views): the shell's colours change with the view direction,
    and off the capture's path nothing else constrains them (the NGP ball: 37.19 -> 38.77 dB). Without a shell
    the views cost accuracy on the path (the demo bunny: 38.27 -> 36.88 dB) and gained nothing off it (15 degrees
    off: 34.80 against 34.64). "on" / "off" as configured ("on" with cameras inside the box: views along their
    path, ``extra_views.path_views``)."""
    count = int(round(fraction * train))
    if mode == "off" or count == 0:
        record.leave_out("extra training views", "turned off by configuration" if mode == "off"
                         else "cameras.extra_views_fraction is 0")
        return 0
    if mode == "auto" and inside.any():
        record.leave_out("extra training views", f"{int(inside.sum())} of {inside.size} cameras are inside the "
                         "field's box (a path through the scene, not around an object): views turned about their "
                         "look-at points would leave the path (cameras.extra_views = \"on\" adds views along it)",
                         cameras_inside=int(inside.sum()))
        return 0
    if mode == "auto" and not fringe_shell:
        record.leave_out("extra training views", "the mesh gets no soft-fringe shell: its colours need no views "
                         "beyond the capture's (on the demo bunny they cost 1.4 dB on the held-out path)")
        return 0
    record.keep("extra training views", "turned on by configuration" if mode == "on" else
                f"{count} views around the {train} training cameras, rendered by the field: the fringe shell's "
                "colours change with the view direction, and off the capture's path only such views constrain "
                "them", count=count)
    return count


def shading_normals(mesh, uses_normals: bool, rounds: int, record: Decisions,
                    roughness: float | None = None) -> int:
    """Rounds of normal smoothing for the shader's normal-based inputs, the facing cosine and the reflected
    direction (``MeshData.normal_smoothing``): ``rounds`` when the mesh's normals are rough (their median turn
    under smoothing above ``rules.ROUGH_NORMALS_DEG``: a surface fused from a NeRF's depths), else 0; without
    such an input (``uses_normals`` False) the normals are not used and nothing is recorded. ``roughness``:
    the turn already measured with ``rounds`` (``ShaderInputs.normal_roughness_deg``), else it is measured."""
    if not uses_normals or rounds <= 0:
        return 0
    rough = mesh.normal_roughness_deg(rounds) if roughness is None else roughness
    measured = {"normal_roughness_deg": rough, "rounds": rounds}
    if rough > rules.ROUGH_NORMALS_DEG:
        record.keep("smoothed shading normals", f"the surface's vertex normals turn a median {rough:.1f} degrees "
                    f"under {rounds} rounds of smoothing (above {rules.ROUGH_NORMALS_DEG:g}): the shader's "
                    "normal-based inputs read the smoothed ones", **measured)
        return int(rounds)
    record.leave_out("smoothed shading normals", f"the surface's vertex normals turn a median {rough:.1f} degrees "
                     f"under smoothing (at most {rules.ROUGH_NORMALS_DEG:g}): they are kept as they are",
                     **measured)
    return 0


def reflected_view_input(mesh, cfg: DistillConfig, use_viewdir: bool, fringe_shell: bool,
                         record: Decisions) -> tuple[bool, float | None]:
    """(feed the shader the view direction reflected about the shading normal, the normals' roughness in
    degrees as ``MeshData.normal_roughness_deg`` measures it with ``texture.normal_smoothing`` rounds, None when
    not measured). "auto" reflects on a one-layer mesh whose normals turn at most
    ``rules.REFLECTION_MAX_ROUGHNESS_DEG`` under smoothing (a level set, not a surface fused from depths). A
    fringe shell's colour is an average along the ray through the fringe, not a reflection off a surface: it
    keeps the direction."""
    mode = cfg.texture.view_input
    if not use_viewdir or mode == "direction":
        return False, None
    if mode == "reflection":
        record.keep("reflected view direction", "turned on by configuration")
        return True, None
    if fringe_shell:
        record.leave_out("reflected view direction", "the mesh's fringe shell sees colours averaged along each "
                         "ray, not reflected off a surface: the shader takes the view direction itself")
        return False, None
    rounds = cfg.texture.normal_smoothing or rules.ROUGHNESS_ROUNDS
    rough = mesh.normal_roughness_deg(rounds)
    turn = f"the surface's vertex normals turn a median {rough:.1f} degrees under {rounds} rounds of smoothing"
    limit = rules.REFLECTION_MAX_ROUGHNESS_DEG
    if rough > limit:
        record.leave_out("reflected view direction", f"{turn} (above {limit:g}): reflected about them the "
                         "direction would scatter highlights; the shader takes the view direction itself",
                         normal_roughness_deg=rough)
        return False, rough
    record.keep("reflected view direction", f"{turn} (at most {limit:g}): the shader takes the view direction "
                "reflected about them, so a highlight is one function of that direction over the whole surface",
                normal_roughness_deg=rough)
    return True, rough


def view_dependence(field: Field, mesh, cfg: DistillConfig, record: Decisions,
                    fringe_shell: bool = False) -> tuple[bool, float | None]:
    """(use the view direction, measured spread). A mesh moved out to a soft fringe's shell keeps it whatever
    the field's own radiance does: a ray crossing the fringe averages colours along its path, so the colour at
    a shell point changes with the direction (gradient ball: held-out interior 24.3 dB without it)."""
    mode = cfg.texture.view_dependence
    if mode == "on" or (mode == "auto" and fringe_shell):
        record.keep("view direction", "turned on by configuration" if mode == "on"
                    else "the mesh's fringe shell sees colours averaged along each ray")
        return True, None
    if mode == "off":
        record.leave_out("view direction", "turned off by configuration")
        return False, None
    spread = rules.measure_view_dependence(field, mesh, seed=cfg.train.seed)
    if spread < cfg.texture.view_threshold:
        record.leave_out("view direction",
                         f"the field's colour barely changes with view direction (mean spread {spread:.4f} < "
                         f"{cfg.texture.view_threshold}); the shader has no view input", spread=spread)
        return False, spread
    record.keep("view direction", f"the field's colour changes with view direction (mean spread {spread:.4f})",
                spread=spread)
    return True, spread


def core_view_dependence(field: Field, mesh, cfg: DistillConfig, use_viewdir: bool, record: Decisions) -> bool | None:
    """Whether the core's shader of a two-layer mesh takes the view direction (None: as ``use_viewdir``).

    A core at the level the field's colour comes from (``geometry.colour_level``, ``mc_colour_level_used``)
    sees no parallax through the fringe, so it needs the direction only when the field's own colour changes
    with it (measured on the core, ``rules.measure_view_dependence``); the shell keeps it (its fringe
    pixels average colours along the ray). Without it the gradient ball's held-out core interior scored 41.3
    against 39.3 dB (``NeuralTextureModel``, ``core_viewdir``)."""
    if (not use_viewdir or mesh.core_faces is None or cfg.texture.view_dependence != "auto"
            or not mesh.stats.get("mc_colour_level_used")):
        return None
    spread = rules.measure_view_dependence(field, mesh.layers()[0], seed=cfg.train.seed)
    if spread >= cfg.texture.view_threshold:
        return None
    record.leave_out("view direction of the core's shader",
                     f"the core sits where the field's colour comes from and that colour barely changes with the "
                     f"view (mean spread {spread:.4f} < {cfg.texture.view_threshold}); only the fringe shell's "
                     "shader takes the direction", spread=spread)
    return False


def surface_source(stats: dict, record: Decisions) -> None:
    """A density field's mesh from its fused surface depths instead of its level set, and why."""
    if "fused_depths_missed" not in stats:
        return
    missed, fused = 100 * stats["level_set_missed"], 100 * stats["fused_depths_missed"]
    measured = dict(level_set_missed=missed, fused_depths_missed=fused)
    if stats.get("level_set_defect") == "tangled":
        folded, fused_folded = 100 * stats["level_set_folded"], 100 * stats["fused_depths_folded"]
        measured.update(level_set_folded=folded, fused_depths_folded=fused_folded)
        if stats.get("surface_from_depths"):
            record.keep("surface from fused depths", f"the density's decimated level set is tangled "
                               f"({folded:.0f}% of adjacent faces folded); the teacher's fused surface depths: "
                               f"{fused_folded:.1f}% folded, {fused:.1f}% of the opaque training pixels missed",
                               **measured)
        else:
            record.leave_out("surface from fused depths", f"the level set is tangled ({folded:.0f}% of "
                                    f"adjacent faces folded) but the fused depths are no better ({fused_folded:.1f}% "
                                    f"folded, {fused:.1f}% of the opaque training pixels missed)", **measured)
        return
    if stats.get("surface_from_depths"):
        faint = ""
        if "fused_faint_pixels" in stats:
            measured["fused_faint_pixels"] = 100 * stats["fused_faint_pixels"]
            faint = (f" ({measured['fused_faint_pixels']:.1f}% of the training pixels, faint but in hazy regions, "
                     f"count as surface there)")
        record.keep("surface from fused depths", f"the density's level set missed {missed:.1f}% of the "
                           f"opaque training pixels (a perforated surface); the teacher's fused surface depths "
                           f"miss {fused:.1f}%{faint}", **measured)
    else:
        record.leave_out("surface from fused depths", f"the level set missed {missed:.1f}% of the opaque "
                                f"training pixels but the fused depths missed more ({fused:.1f}%)", **measured)


def atlas_pages(stats: dict, record: Decisions) -> None:
    """An atlas side above ``texture.page_size``: the pages it was packed into."""
    from ..geometry.unwrap import atlas_shape

    height, side, pages = atlas_shape(stats)
    if pages > 1:
        record.keep("atlas pages", f"the {stats['uv_resolution']}x{stats['uv_resolution']} atlas is above "
                           f"texture.page_size ({side}): its charts, at the same texels per unit, fill {pages} "
                           f"pages of {side}x{side}, played as a texture array", pages=pages, page_size=side)


def atlas_side(tex_res: int, density: dict, hi: int, record: Decisions) -> None:
    """The atlas side the texel density chose (``density``: ``stages.geometry.choose_atlas_side``'s figures),
    capped at ``hi`` (``texture.max_resolution``) and by the training budget."""
    capped = density["exact"] > hi
    ppt = rules.PIXELS_PER_TEXEL
    record.leave_out(
        "texels beyond the training views' detail",
        f"atlas {tex_res}x{tex_res} chosen from texel density: the training views see {density['pixels']:.0f} "
        f"pixels of surface on {100 * density['uv_area']:.1f}% of the atlas, one texel per {ppt:g}x{ppt:g} pixels "
        f"at {density['exact']:.0f}"
        + (f" (set by the fringe shell: {density['shell_pixels']:.0f} pixels on "
           f"{100 * density['shell_uv_area']:.1f}% of the atlas at a quarter of the texel density)"
           if density.get("from_shell") else "")
        + (f" (capped at max_resolution {hi})" if capped else "")
        + (f"; limited to {density['budget']} by the training budget ({density['samples']} samples, "
           f"{rules.SAMPLES_PER_TEXEL} per used texel)" if density["budget"] < density["exact"] else ""),
        side=tex_res, **{k: v for k, v in density.items() if isinstance(v, (int, float))})


def larger_atlas_for_small_charts(tex_res: int, charts: int, density: dict, record: Decisions) -> None:
    """The atlas unwrapped again at a larger side because its charts' padding left too few texels."""
    record.keep(
        "a larger atlas for small charts",
        f"at {density['regrown_from']}x{density['regrown_from']} the {charts} UV charts' padding left "
        f"{100 * density['texel_yield']:.0f}% of the texels the surface needs; unwrapped again at "
        f"{tex_res}x{tex_res} ({100 * density['texel_yield_after']:.0f}%)",
        side=tex_res, texel_yield=density["texel_yield"], texel_yield_after=density["texel_yield_after"])


def view_weighted_texels(weights: np.ndarray, record: Decisions) -> None:
    """Charts sized by the texel densities the views want (``weights`` (F,), ``rules.view_texel_weights``)."""
    spread = np.percentile(weights, [10, 50, 90])
    record.keep(
        "texels where the views need them",
        f"charts (within tiles of 1/48 of the scene) sized by the training pixels per unit area that the view "
        f"seeing them largest gives, not by their 3D area (texture.view_weighted_texels): wanted densities "
        f"span {spread[2] / spread[0]:.0f}x between the 10th and 90th percentile of faces",
        p10=float(spread[0]), p50=float(spread[1]), p90=float(spread[2]))


def unseen_faces(culled: int, record: Decisions) -> None:
    """Faces culled because no training camera (or its neighbours) saw them."""
    if culled:
        record.leave_out("unseen faces", f"{culled} faces seen by no training camera were culled before "
                                         "unwrapping (they get no texels)", culled_faces=culled)


def training_steps(plan, steps: int, needed: int, used: float, record: Decisions) -> str:
    """Record the training length (``steps``; ``needed`` would give ``rules.TARGET_SAMPLES_PER_TEXEL`` samples to
    each of ``used`` texels) against ``plan`` (a ``TrainingPlan``); returns the reason."""
    target = rules.TARGET_SAMPLES_PER_TEXEL
    if plan.configured_steps:
        why = f"{steps} steps as configured ({needed} would give {target} samples per used texel)"
    elif needed > plan.max_steps:
        why = (f"{steps} steps: the {plan.time_budget_s:.0f} s cap (at {plan.steps_per_second:.0f} steps/s) "
               f"affords fewer than the {needed} that give {target} samples to each of {int(used)} used texels")
    else:
        why = (f"at most {steps} steps: they give {target} samples to each of {int(used)} used texels (at least "
               f"{rules.MIN_TRAIN_STEPS}); training stops sooner if the held-back pixels stop improving")
    record.leave_out("training beyond the atlas's needs", why, steps=int(steps), needed_steps=int(needed))
    return why


def render_widths(test_width: int, train_width: int, eval_width: int, cfg: DistillConfig, record: Decisions) -> None:
    """The teacher's and the held-out frames' widths, when the cameras' own width capped the configured ones."""
    if (train_width, eval_width) == (cfg.teacher.train_width, cfg.eval.width or test_width):
        return
    record.leave_out(
        "renders beyond the cameras' resolution",
        f"the cameras are {test_width} pixels wide: the teacher renders at {train_width} and the held-out "
        f"frames at {eval_width} pixels (the teacher at most {rules.MAX_UPSCALE:g}x the cameras' width, the "
        f"held-out frames at most eval.max_upscale = {cfg.eval.max_upscale:g}x; 0 lifts that cap), not the "
        f"configured {cfg.teacher.train_width} / {cfg.eval.width}", train_width=train_width,
        eval_width=eval_width)


def baked_leftovers(entries: list[dict], record: Decisions) -> None:
    """What baking left out (``entries``: the manifest's ``left_out`` rows it added) into the run's record."""
    for entry in entries:
        record.leave_out(entry["component"], entry["reason"])


def vector_quantization_skipped(touched: int, quantize_above: int, num_codes: int, record: Decisions) -> None:
    """Texels kept exact because the ``touched`` ones fit the index texture."""
    record.leave_out("vector quantization", f"the {touched} texels training touched fit the index "
                     f"texture (at most texture.quantize_above = {quantize_above}): each keeps its "
                     f"own feature, exact, instead of the nearest of {num_codes} k-means codes",
                     touched_texels=touched)
