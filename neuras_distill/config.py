"""``DistillConfig``: every setting of a run, with its default in exactly one place.

Presets (``configs/*.toml``, installed as ``neuras_distill.configs``) only override these defaults; a user's own
TOML file does the same. Each field's docstring is what it means and its unit.
"""

from __future__ import annotations

import dataclasses
import sys

if sys.version_info >= (3, 11):
    import tomllib
else:                       # Python 3.10: the same parser, released as tomli
    import tomli as tomllib
from dataclasses import dataclass, field, fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Literal, get_args

from .errors import BadInputError, require

#: A component the run decides on by measurement ("auto") or that the user forces.
Mode = Literal["auto", "on", "off"]
#: Where a fringed density field's core mesh sits (``GeometryConfig.core_level``).
CoreLevel = Literal["colour", "surface"]
#: Where the shell around a colour-level core comes from (``GeometryConfig.shell``).
ShellSource = Literal["offset", "level"]
#: What the shader's direction input is (``TextureConfig.view_input``).
ViewInput = Literal["auto", "direction", "reflection"]
#: Where a density field's mesh comes from (``GeometryConfig.surface``).
SurfaceSource = Literal["auto", "depths"]
#: Largest mesh the UV unwrap accepts (xatlas's time grows faster than linearly; larger face budgets are refused
#: when the configuration is read, ``geometry/unwrap.py``).
MAX_UNWRAP_FACES = 200_000


def _require_choice(value, choices, name: str) -> None:
    """One clear error when ``value`` is not one of the Literal alias ``choices``'s values."""
    allowed = get_args(choices)
    require(value in allowed, f"{name} must be {', '.join(allowed[:-1])} or {allowed[-1]}, got {value!r}")


@dataclass(frozen=True)
class CameraConfig:
    """Cameras generated for fields that bring none, the held-out split, and extra training views."""

    num_views: int = 48
    """Cameras generated for fields that bring none (an orbit framing the scene)."""
    width: int = 1920
    """Image width of generated cameras (the evaluation frames are resized from these)."""
    height: int = 1080
    """Image height of generated cameras."""
    test_every: int = 12
    """Every n-th camera is held out for evaluation; the rest train."""
    extra_views: Mode = "auto"
    """Add training views near the training cameras, rendered by the field (``render/extra_views.py``): "auto"
    when the mesh gets a soft-fringe shell (its colours change with the view direction) and every camera looks
    at the scene from outside its box; "on" (cameras inside the box, a drive: views along their path,
    ``extra_views.path_views``), "off". Held-out cameras are never used (``choices.extra_views``)."""
    extra_views_fraction: float = 0.5
    """Extra views as a fraction of the training views."""
    extra_views_deg: float = 10.0
    """Each extra view is a training camera turned about its look-at point by up to this many degrees."""

    def validate(self) -> "CameraConfig":
        require(self.num_views >= 2, "need at least 2 views (some train, some held out)")
        _require_choice(self.extra_views, Mode, "cameras.extra_views")
        require(0.0 <= self.extra_views_fraction <= 8.0,
                f"cameras.extra_views_fraction must be in 0..8 (of the training views), got {self.extra_views_fraction}")
        require(0.0 < self.extra_views_deg <= 45.0,
                f"cameras.extra_views_deg must be in 0..45 degrees (exclusive of 0), got {self.extra_views_deg}")
        return self


@dataclass(frozen=True)
class TeacherConfig:
    """The teacher: the field volume-rendered for every training view (and the "before" renderer)."""

    num_steps: int = 256
    """Ray-marching steps across the field's box diagonal (the teacher and the "before" renderer)."""
    far_steps: int = 256
    """Samples per ray between the near and far planes of an unbounded field (one trained with scene
    contraction, as nerfstudio's nerfacto): the ground, buildings and sky beyond the foreground box, spaced
    linearly near the camera and uniformly in disparity beyond (render/far_region.py). 0 leaves that space to
    the field's background colour. Fields without a far region ignore it."""
    occupancy_resolution: int = 128
    """Cells along each side of the occupancy grid the teacher skips empty space with (``render/occupancy.py``;
    a field's own grid, as an Instant-NGP snapshot's, is used instead where it has one). Building it samples a
    density field twice per cell (4.2 million points at 128, about 20 s for a plain-PyTorch nerfacto field on 2
    CPU cores), an SDF once; each halving builds 8x faster and skips less empty space."""
    train_width: int = 640
    """Width in pixels of the training renders (height follows the cameras' aspect ratio)."""
    precision: str = "fp32"
    """Field evaluation: "fp32", or "fp16" (half hash-grid tables and MLPs, float32 compositing; as Instant-NGP
    evaluates). Applies to every field evaluation of the run: the teacher, marching cubes, the "before" renders."""

    def validate(self) -> "TeacherConfig":
        from .precision import check_precision

        require(8 <= self.occupancy_resolution <= 1024,
                f"teacher.occupancy_resolution must be in 8..1024 cells, got {self.occupancy_resolution}")
        check_precision(self.precision)
        return self


@dataclass(frozen=True)
class GeometryConfig:
    """The mesh: marching cubes, cleanup, decimation, culling, UV unwrap."""

    grid_resolution: int = 192
    """Marching-cubes lattice points along the longest side of the field's box."""
    face_budget: int = 40_000
    """Maximum number of faces after quadric decimation."""
    cull_unseen: bool = True
    """Drop faces that no camera near the training cameras sees."""
    cull_margin_deg: float = 15.0
    """Culling is conservative: faces seen by each training camera turned by this angle (degrees) about its
    look-at point are kept too, so held-out and user views a little outside the training range see no holes."""
    enclose_fringe: Mode = "auto"
    """"auto": move the iso-level outwards until the mesh covers the pixels where the field is partly opaque
    (its soft fringe), when the background is one constant colour; "on", "off"."""
    core_level: CoreLevel = "colour"
    """Where a fringed density field's core mesh sits (with a fringe shell): "colour" (where its opaque training
    rays terminate, ``geometry/colour_level.py``) or "surface" (the field's surface level, where the silhouette
    is). A texture at the surface level sees the colour through parallax that changes with the view; at the
    colour level the shell draws the whole fade (docs/decisions.md "Where the colour comes from"). The core's
    shader drops the view direction when the field's own colour does not depend on it
    (``pipeline.choices.core_view_dependence``)."""
    shell: ShellSource = "offset"
    """Where the fringe shell around a colour-level core comes from: "offset" (the core pushed out by the
    smallest of a series of distances that encloses the fringe, ``marching.offset_grid``) or "level" (the
    density's own lower levels, halving until they enclose it). A trained NeRF's fringe is speckle and its low
    levels are fog, which a level shell draws as pale faceted shards
    (docs/decisions.md "The shell is the core pushed out")."""
    surface: SurfaceSource = "auto"
    """Where a density field's mesh comes from. "auto": its level set on the marching-cubes grid, meshed again
    from the surface depths fused over the training views when xatlas cannot unwrap that level set (a trained
    NeRF's foam interior). "depths": always from the fused depths; the stability check chooses it when parts of
    the field are thinner than a voxel even at its largest grid (a lattice misses them: the level set is a
    perforated foam). SDF fields always use their level set."""
    cull_back_faces: bool = True
    """Cull back faces when rasterizing (G-buffers and playback alike): invisible on closed meshes, and
    playback shades half as many fragments."""
    unwrap_timeout_s: float = 120.0
    """Time limit for the UV unwrap (xatlas runs in a child process)."""

    def validate(self) -> "GeometryConfig":
        require(self.face_budget >= 4, f"face budget must be at least 4 faces, got {self.face_budget}; "
                                       "pass e.g. --face-budget 40000")
        require(self.face_budget <= MAX_UNWRAP_FACES,
                f"face budget {self.face_budget} is more than the UV unwrap handles ({MAX_UNWRAP_FACES} faces); "
                f"pass --face-budget {MAX_UNWRAP_FACES} or less")
        require(self.grid_resolution >= 16, f"grid resolution must be at least 16, got {self.grid_resolution}")
        require(0.0 <= self.cull_margin_deg < 90.0,
                f"cull_margin_deg must be in 0..90 degrees, got {self.cull_margin_deg}")
        _require_choice(self.surface, SurfaceSource, "geometry.surface")
        _require_choice(self.shell, ShellSource, "geometry.shell")
        _require_choice(self.core_level, CoreLevel, "core_level")
        _require_choice(self.enclose_fringe, Mode, "enclose_fringe")
        return self


@dataclass(frozen=True)
class TextureConfig:
    """The neural texture: feature atlas, codebook, MLP shader, and what playback draws."""

    resolution: int = 0
    """Side of the square feature atlas in texels. 0 (default): chosen per run from texel density, one texel per
    2 x 2 pixels of the training view that sees it largest (``pipeline.rules.texel_density_resolution``),
    limited by the training budget (256 samples per used texel) and ``max_resolution``; reported in
    ``left_out``. A fixed side overrides it."""
    max_resolution: int = 2048
    """Upper limit of the automatic atlas side."""
    page_size: int = 4096
    """Largest side of one atlas page (texture). An atlas side above it is unwrapped into several pages of this
    side at the same texels per unit (``geometry.unwrap(page_size=)``), played as a texture array of as many
    layers and exported to glTF as one material per page (docs/architecture.md "Atlas pages"). 4096 is what
    every WebGL2 browser and GPU holds; at or below it nothing changes."""
    view_weighted_texels: bool = False
    """Size each UV chart by the texel density its faces want (training pixels per unit area in the view that
    sees them largest) instead of by its 3D area, charts cut into tiles of 1/48 of the scene first
    (``geometry.unwrap.unwrap(face_weights=...)``). For scenes seen from a path through them, whose near
    surfaces need far more texels per square metre than their distant ones (the city preset turns it on; the
    street has not been measured with it). One-layer meshes only."""
    feature_dim: int = 8
    """Channels per texel (D)."""
    coarse_factor: int = 8
    """A coarse feature level under the atlas, this many times fewer texels a side, trained with it and summed
    into every texel's feature before baking (``neural.texture.NeuralTexture``; the bundle does not change); 1:
    none. A run keeps it when training gives each used texel fewer samples than the texel rule asks for, and says
    so in ``left_out`` otherwise (``pipeline.choices.coarse_level``). Flat surfaces, whose texels each see few
    training samples, converge in it: the street's smooth region 36.64 -> 38.31 dB with 8 (at 1024² against
    512² alone, 2000 steps; docs/decisions.md "A coarse feature level under the atlas")."""
    num_codes: int = 32768
    """Vector-quantizer codebook size (K); codes never used are dropped at bake time. 32768, not the paper's
    1024: a smooth colour gradient needs finer steps than k-means of fewer codes gives, and a played 1080p view
    magnifies them (docs/decisions.md "Codebook size"). The index texture is uint16 (up to 65535 codes); the
    codebook texture wraps past GL's largest side."""
    quantize: bool = True
    """Vector-quantize the atlas (``num_codes``). False stores every distinct texel feature as its own code
    (exact; only when there are at most 65535 of them: the bench's "no VQ" variant)."""
    quantize_above: int = 65535
    """With ``quantize``, k-means runs only when training touched more texels than this; at or below it every
    trained texel keeps its own feature as its code (exact; the uint16 index holds 65535), which scores better
    than k-means at the cost of a larger codebook (docs/decisions.md "k-means only where it compresses").
    0: always k-means."""
    hidden: int = 32
    """Hidden units of the MLP shader (as NeuRas). 32 scores better than 16 on every scene measured and trains
    as fast on a CPU; on a GPU's deferred path shading is a small compute pass, and on software OpenGL a 1080p
    frame costs more (docs/decisions.md "Shader width")."""
    shell_hidden: int = 32
    """Hidden units of the fringe shell's own MLP shader (a two-layer mesh, ``geometry.enclose_fringe``; 0: as
    ``hidden``). The shell draws a soft fringe's whole fade, a function of the view direction, the facing
    cosine and the colour under it, and only its pixels outside the core's silhouette run it
    (docs/decisions.md "Two layers, a shader each")."""
    output_layers: int = 3
    """Colour layers the MLP shader predicts and composites into rgb (NeuRas's rendering layers; each an rgb
    and an opacity, the last opaque; docs/decisions.md "Composited output layers"). 1: one rgb."""
    num_layers: int = 2
    """Linear layers of the MLP shader (2: one hidden layer; a second hidden layer scored no better and costs
    about a fifth more frame time on software OpenGL)."""
    view_dependence: Mode = "auto"
    """"auto" (measure the field and drop the view direction when colour does not depend on it), "on", "off"."""
    view_threshold: float = 0.01
    """Mean colour change (0..1) over view directions below which "auto" drops the view direction."""
    view_input: ViewInput = "auto"
    """The shader's direction input where it takes one: "direction" (the view direction, as NeuRas),
    "reflection" (the view direction reflected about the shading normal, ``MeshData.vertex_normals``: a
    highlight is then one function of that direction over the whole surface instead of one per texel), or
    "auto" (the reflection on a one-layer mesh whose normals are smooth enough,
    ``rules.REFLECTION_MAX_ROUGHNESS_DEG``; else the direction;
    docs/decisions.md "The reflected view direction")."""
    normal_smoothing: int = 20
    """Rounds of one-ring averaging of the shading normals when the shader takes the facing cosine (a mesh with a
    fringe shell) or the reflected view direction (``view_input``; ``MeshData.normal_smoothing``) and the normals
    are rough (``rules.ROUGH_NORMALS_DEG``): a
    fringe fades with the surface's large-scale orientation, while a surface fused from a trained NeRF's depths
    is bumpy (docs/decisions.md "Smoothed shading normals"). 0: never."""
    soft_silhouettes: Mode = "auto"
    """The soft-silhouette pass (``playback/silhouette.py``): "auto" (when the field's fringe is at least 1.5
    pixels wide at the playing resolution), "on", "off". It gains 1-4 dB on soft-edged fields and costs a third
    to two thirds more frame time on software OpenGL, a fraction of a millisecond on a GPU (docs/decisions.md
    "Soft silhouettes"). "off" keeps the frame time."""

    def validate(self) -> "TextureConfig":
        t = self
        require(t.shell_hidden >= 0, f"texture.shell_hidden must be 0 (as hidden) or positive, got {t.shell_hidden}")
        _require_choice(t.soft_silhouettes, Mode, "soft_silhouettes")
        require(t.resolution == 0 or 16 <= t.resolution <= 8192,
                f"texture resolution must be 0 (automatic) or in 16..8192, got {t.resolution}")
        require(64 <= t.max_resolution <= 8192, f"max texture resolution must be in 64..8192, got {t.max_resolution}")
        require(64 <= t.page_size <= 16384, f"texture.page_size must be in 64..16384 texels, got {t.page_size}")
        require(0 <= t.normal_smoothing <= 1000,
                f"texture.normal_smoothing must be in 0..1000 rounds, got {t.normal_smoothing}")
        require(1 <= t.feature_dim <= 32, f"feature_dim must be in 1..32, got {t.feature_dim}")
        require(1 <= t.output_layers <= 8, f"texture.output_layers must be in 1..8 (1: one rgb), got "
                                           f"{t.output_layers}")
        require(1 <= t.coarse_factor <= 64, f"texture.coarse_factor must be in 1..64 (1: no coarse level), got "
                                           f"{t.coarse_factor}")
        require(2 <= t.num_codes <= 65535, f"num_codes must be in 2..65535, got {t.num_codes}")
        require(0 <= t.quantize_above <= 65535, f"texture.quantize_above must be in 0..65535 texels (what the uint16 "
                f"index holds; 0: always k-means), got {t.quantize_above}")
        _require_choice(t.view_dependence, Mode, "view_dependence")
        _require_choice(t.view_input, ViewInput, "view_input")
        return self


@dataclass(frozen=True)
class SkyboxConfig:
    """Neural skyboxes for what lies beyond the mesh (unbounded scenes)."""

    mode: Mode = "auto"
    """"auto" (skyboxes when training rays miss the mesh and the field's background is not one constant
    colour), "on", "off"."""
    layers: int = 0
    """Nested cube layers (NeuRas uses 6 for driving scenes). 0 (default): 4, or 8 when at least 20% of the
    pixels the skyboxes learn look below the horizon (ground beyond the mesh, whose distance changes across the
    view; ``pipeline.rules.SKY_GROUND_SHARE``)."""
    near: float = 0.0
    """Half size of the innermost layer in world units (0: the foreground box's half diagonal, or 1.25x the
    farthest camera from its centre along an axis, whichever is larger). It must enclose every camera."""
    far: float = 0.0
    """Half size of the outermost layer (0: 16x near; the paper spans 150 m .. 2.4 km). Layers between are
    spaced geometrically."""
    resolution: int = 64
    """Texels along each face side of each layer."""
    feature_dim: int = 8
    """Channels per skybox texel."""
    num_codes: int = 0
    """Size of the skyboxes' codebook (their own, as in the paper). 0 (default): 4096, or 16384 when they hold
    ground (``pipeline.rules.SKY_CODES``; the same 20% below the horizon that asks for 8 layers): a sky is a
    smooth gradient, which 256 codes mottle, and a ground to the horizon adds a texture's worth of features that
    4096 codes lose 2-3 dB on (docs/decisions.md "Skyboxes")."""
    hidden: int = 16
    """Hidden units of the skybox MLP."""
    ablation: bool = True
    """Also play the bundle without its skybox pass and report the PSNR drop."""

    def validate(self) -> "SkyboxConfig":
        sb = self
        _require_choice(sb.mode, Mode, "skybox mode")
        require(0 <= sb.layers <= 16, f"skybox layer count must be in 0..16 (0: automatic), got {sb.layers}")
        require(sb.near >= 0 and sb.far >= 0, f"skybox distances must be positive (0 = automatic), got "
                                              f"near={sb.near}, far={sb.far}")
        require(not (sb.near and sb.far) or sb.far > sb.near or sb.layers == 1,
                f"skybox layers must nest: far ({sb.far}) must be larger than near ({sb.near})")
        require(2 <= sb.resolution <= 4096, f"skybox resolution must be in 2..4096, got {sb.resolution}")
        require(1 <= sb.feature_dim <= 32 and (sb.num_codes == 0 or 2 <= sb.num_codes <= 65535) and sb.hidden >= 1,
                "skybox feature_dim must be in 1..32, num_codes in 2..65535 (0: automatic), hidden >= 1")
        return self


@dataclass(frozen=True)
class TrainConfig:
    """Fitting the atlas, codebook and shader to the teacher's renders."""

    steps: int = 0
    """Optimisation steps. 0 (default): planned per run from what the scene needs, 2048 training samples per
    used texel of the atlas (``pipeline.rules.training_steps``), stopped earlier when held-back training
    pixels stop improving (``neural.convergence``) or at the time budget; the report says which rule stopped it
    (``training_stop``). Configured steps run to the end unless a time budget is set too."""
    time_budget_s: float = 0.0
    """Training's own cap in seconds. 0 (default): what ``run_budget_s`` leaves it, or
    ``pipeline.rules.TRAIN_CAP_S`` (600 s) without one."""
    run_budget_s: float = 0.0
    """The whole run's cap in seconds (``--time-budget``): training gets what the stages before it leave, less
    the evaluation's estimated time. 0 (default): no cap on the run."""
    lr: float = 0.01
    """Adam learning rate of the shader and codebook (NeuRas uses 0.01)."""
    texture_lr_scale: float = 9.0
    """The feature atlases (the mesh's and the skyboxes') learn at this multiple of ``lr`` (a texel sees a few
    samples a step, the shader every sample; docs/decisions.md "Training batches")."""
    batch_patches: int = 128
    """Patches per step (``batch_patches * patch**2`` pixels: 8192 by default)."""
    patch: int = 8
    """Patch side in pixels (the SSIM term needs patches of at least 7). Small patches draw a step's pixels from
    many views and places, so its gradient is less redundant (docs/decisions.md "Training batches")."""
    ssim_weight: float = 0.0
    """Weight of the (1 - SSIM) term; the L2 term has weight 1. Off by default: at 0.2 its gradient outweighed
    the L2 term's by about 100x and training traded colour for structure (docs/decisions.md "L2 only")."""
    vq_warmup: float = 1.0
    """Fraction of the steps that train continuous features before the features are quantized (k-means
    initialised codebook, straight-through training after). 1.0: quantize once, after training
    (docs/decisions.md "Quantize after training")."""
    seed: int = 0
    """Random seed for initialisation and batches."""
    checkpoint_every_s: float = 30.0
    """Seconds of training between checkpoints in the run's work area (a killed run resumes from the last
    one; ``neural.train_checkpoint``). Does not change the result, so it is not part of any cache key."""

    def validate(self) -> "TrainConfig":
        tr = self
        require(tr.steps >= 0, f"training steps must be >= 1, or 0 for automatic, got {tr.steps}")
        require(tr.checkpoint_every_s > 0, f"train.checkpoint_every_s must be > 0 seconds, got {tr.checkpoint_every_s}")
        require(tr.time_budget_s >= 0,
                f"training time budget must be >= 0 seconds (0: automatic), got {tr.time_budget_s}")
        require(tr.run_budget_s >= 0,
                f"the run's time budget must be >= 0 seconds (0: none), got {tr.run_budget_s}; pass --time-budget 600")
        require(0.0 < tr.lr <= 1.0 and 0.0 < tr.texture_lr_scale <= 100.0,
                f"train.lr must be in (0, 1] and train.texture_lr_scale in (0, 100], got {tr.lr} and "
                f"{tr.texture_lr_scale}")
        require(1 <= tr.patch <= 64 and 1 <= tr.batch_patches <= 4096,
                f"train.patch must be in 1..64 pixels and train.batch_patches in 1..4096, got {tr.patch} and "
                f"{tr.batch_patches}")
        require(0.0 <= tr.vq_warmup <= 1.0, f"vq_warmup must be in 0..1 (1: quantize after training), "
                                            f"got {tr.vq_warmup}")
        return self


@dataclass(frozen=True)
class EvalConfig:
    """The held-out evaluation: frame size, timing, the error-against-run-time curve."""

    width: int = 1920
    """Width of held-out frames for PSNR/SSIM and FPS (height follows the cameras' aspect ratio); 0: the
    cameras' own size."""
    max_upscale: float = 2.0
    """Held-out frames are at most this many times the cameras' own width (``rules.MAX_UPSCALE``); 0: no
    cap, e.g. to time a dataset of small images at a display's 1920 pixels."""
    fps_frames: int = 30
    """Timed bundle frames (after warm-up) for the median frame time."""
    runtime_steps: list[int] = field(default_factory=lambda: [32, 64, 128])
    """Ray-marching step counts at which the field is also timed for the error-vs-runtime curve."""

    def validate(self) -> "EvalConfig":
        require(self.max_upscale >= 0, f"eval.max_upscale must be 0 (no cap) or positive, got {self.max_upscale}")
        return self


@dataclass(frozen=True)
class DistillConfig:
    """Every setting of a run, one table per stage (the TOML tables ``[cameras]``, ``[teacher]``, ...)."""

    cameras: CameraConfig = field(default_factory=CameraConfig)
    teacher: TeacherConfig = field(default_factory=TeacherConfig)
    geometry: GeometryConfig = field(default_factory=GeometryConfig)
    texture: TextureConfig = field(default_factory=TextureConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    skybox: SkyboxConfig = field(default_factory=SkyboxConfig)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def validate(self) -> "DistillConfig":
        """Every section's own checks, then those across sections; ``self`` (unchanged: it is frozen)."""
        for section in (self.cameras, self.teacher, self.geometry, self.texture, self.train, self.eval, self.skybox):
            section.validate()
        require((self.eval.width == 0 or self.eval.width >= 16) and self.teacher.train_width >= 16,
                "image widths must be at least 16 (eval width 0: the cameras' own size)")
        return self

    def updated(self, overrides: dict, where: str = "overrides") -> "DistillConfig":
        """A validated copy with ``overrides`` (nested dicts, as ``load_config``'s) applied; ``self`` is unchanged:
        ``cfg.updated({"geometry": {"grid_resolution": 48}})``."""
        return _merged(self, overrides, where).validate()


def _merged(target, overrides: dict, where: str):
    """A copy of the frozen dataclass ``target`` with the nested ``overrides`` applied, each value checked for
    its setting's type (``where``: what to name in an error)."""
    names = {f.name: f for f in fields(target)}
    changes = {}
    for key, value in overrides.items():
        require(key in names, f"{where}: unknown setting {key!r}; known: {', '.join(sorted(names))}")
        current = getattr(target, key)
        if is_dataclass(current):
            require(isinstance(value, dict), f"{where}: [{key}] must be a table")
            changes[key] = _merged(current, value, f"{where} [{key}]")
            continue
        if isinstance(current, bool):
            require(isinstance(value, bool), f"{where}: {key} must be true or false")
        elif isinstance(current, (int, float)) and not isinstance(current, bool):
            require(isinstance(value, (int, float)) and not isinstance(value, bool),
                    f"{where}: {key} must be a number")
            value = type(current)(value) if isinstance(current, float) or float(value).is_integer() else value
        changes[key] = value
    return dataclasses.replace(target, **changes)


def preset_names() -> list[str]:
    return sorted(p.name[:-5] for p in resources.files("neuras_distill.configs").iterdir()
                  if p.name.endswith(".toml"))


def load_config(preset: str | None = None, path: str | Path | None = None,
                overrides: dict | None = None) -> DistillConfig:
    """Defaults, then a preset by name, then a user TOML file, then explicit overrides (nested dicts)."""
    cfg = DistillConfig()
    if preset:
        require(preset in preset_names(), f"unknown preset {preset!r}; known: {', '.join(preset_names())}")
        text = (resources.files("neuras_distill.configs") / f"{preset}.toml").read_text()
        cfg = _merged(cfg, tomllib.loads(text), f"preset {preset}")
    if path:
        path = Path(path)
        require(path.is_file(), f"config file {path} does not exist")
        try:
            data = tomllib.loads(path.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise BadInputError(f"config file {path} is not valid TOML: {exc}") from None
        cfg = _merged(cfg, data, str(path))
    if overrides:
        cfg = _merged(cfg, overrides, "overrides")
    return cfg.validate()
