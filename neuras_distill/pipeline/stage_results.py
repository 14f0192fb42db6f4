"""What the stages hand on, as small typed results. The expensive ones are stored and reused by the work
area (:class:`pipeline.cache.StageCache`): each of those has ``save(folder)`` and ``load(folder)``.

Flow (``pipeline.run``): cameras -> :class:`CameraSplit` -> teacher -> :class:`TeacherResult` and
:class:`TrainingPlan` -> geometry -> :class:`GeometryResult` and :class:`ShaderInputs` -> gbuffer ->
:class:`TrainingViews` and :class:`Backdrop` -> distill -> :class:`DistilledModel` -> bake -> ``Bundle`` ->
evaluate -> :class:`Evaluation` (with the held-out :class:`FieldViews`) -> the report.

Frames: teacher and held-out renders are per camera, row 0 at the top of the image; meshes are in world
coordinates; G-buffers are rasterized relative to the run's origin (``pipeline.run``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..geometry.mesh import MeshData
from ..playback.gbuffer import GBuffer
from ..render.cameras import Cameras
from .cache import load_arrays, load_json, save_arrays, save_json

if TYPE_CHECKING:
    from ..neural.model import NeuralTextureModel
    from ..neural.skybox import SkyboxLayers, SkyboxModel


@dataclass
class CameraSplit:
    """The run's cameras: ``train`` at the teacher's width, ``test`` (held out) at the evaluation's, and the
    skybox layers planned from all camera centres (None when skyboxes are off)."""

    train: Cameras
    test: Cameras
    sky_layers: SkyboxLayers | None = None


@dataclass
class TeacherResult:
    """The field's renders of the training views.

    Attributes:
        images: (N, H, W, 3) float32 colours; opacities: (N, H, W) float32;
        surface_depths, fringe_depths: (N, H, W) float32 ray distances (``render.volume``);
        seconds: wall time of the rendering (the training budget is a share of it).
    """

    images: np.ndarray
    opacities: np.ndarray
    surface_depths: np.ndarray
    fringe_depths: np.ndarray
    seconds: float

    @staticmethod
    def write_views(folder: Path, renders, seconds: float) -> None:
        """Store per-view renders (``render.field_renders.FieldRenders``) as one ``.npy`` per attribute (what
        :meth:`load` reads), moving each view into the files and dropping it from ``renders`` as it goes: never a
        stacked copy in memory beside the lists."""
        lists = {"images": renders.images, "opacities": renders.opacities,
                 "surface_depths": renders.surface_depths, "fringe_depths": renders.fringe_depths}
        for name, views in lists.items():
            first = np.asarray(views[0])
            out = np.lib.format.open_memmap(folder / f"{name}.npy", mode="w+", dtype=np.float32,
                                            shape=(len(views), *first.shape))
            for i in range(len(views)):
                out[i] = views[i]
                views[i] = None
            out.flush()
            del out
        save_json(folder, "teacher.json", {"seconds": float(seconds)})

    @classmethod
    def load(cls, folder: Path, mmap: bool = False) -> "TeacherResult":
        arrays = load_arrays(folder, "images", "opacities", "surface_depths", "fringe_depths", mmap=mmap)
        return cls(*arrays, seconds=float(load_json(folder, "teacher.json")["seconds"]))


@dataclass
class FieldViews:
    """The field's renders of the held-out views (the "before"): images (N, H, W, 3), opacities (N, H, W),
    seconds per frame (N,) as measured when they were rendered."""

    images: list
    opacities: list
    seconds: list

    def save(self, folder: Path) -> None:
        save_arrays(folder, images=np.stack(self.images), opacities=np.stack(self.opacities))
        save_json(folder, "field_views.json", {"seconds": [float(s) for s in self.seconds]})

    @classmethod
    def load(cls, folder: Path) -> "FieldViews":
        images, opacities = load_arrays(folder, "images", "opacities")
        return cls(list(images), list(opacities), list(load_json(folder, "field_views.json")["seconds"]))


@dataclass
class GeometryResult:
    """The unwrapped mesh (world coordinates, ``MeshData`` with ``stats``) and how its atlas side was chosen
    (``density``: texel-density figures, {} when the side was configured)."""

    mesh: MeshData
    density: dict

    def save(self, folder: Path) -> None:
        self.mesh.save_npz(folder / "mesh.npz")
        save_json(folder, "geometry.json", {"stats": self.mesh.stats, "density": self.density})

    @classmethod
    def load(cls, folder: Path) -> "GeometryResult":
        mesh = MeshData.load_npz(folder / "mesh.npz")
        info = load_json(folder, "geometry.json")
        mesh.stats = info["stats"]
        return cls(mesh, info["density"])


def load_gbuffer(folder: Path, mmap: bool = False) -> GBuffer:
    """The G-buffer ``playback.rasterize.rasterize_gbuffer(..., out=folder)`` wrote, one ``.npy`` per attribute
    (``mmap``: memory-mapped, ``cache.load_arrays``)."""
    uv, face_id, coverage, depth = load_arrays(folder, "uv", "face_id", "coverage", "depth", mmap=mmap)
    normal = load_arrays(folder, "normal", mmap=mmap)[0] if (folder / "normal.npy").exists() else None
    return GBuffer(uv, face_id, coverage, depth, normal)


@dataclass
class TrainedModel:
    """The distill stage's result: the trained model and skybox (state dicts, plus the touched-texel masks,
    which are not part of a state dict) and the training log (``TrainLog.as_dict()``)."""

    model_state: dict
    skybox_state: dict | None
    touched: list
    log: dict

    @classmethod
    def of(cls, model, skybox, log: dict) -> "TrainedModel":
        touched = [model.touched.clone()] + ([skybox.atlas.touched.clone()] if skybox is not None else [])
        return cls(model.state_dict(), skybox.state_dict() if skybox is not None else None, touched, log)

    def load_into(self, model, skybox) -> None:
        model.load_state_dict(self.model_state)
        model.touched.copy_(self.touched[0])
        if skybox is not None:
            skybox.load_state_dict(self.skybox_state)
            skybox.atlas.touched.copy_(self.touched[1])
        model.eval()
        if skybox is not None:
            skybox.eval()

    def save(self, folder: Path) -> None:
        torch.save({"model": self.model_state, "skybox": self.skybox_state, "touched": self.touched},
                   folder / "model.pt")
        save_json(folder, "train_log.json", self.log)

    @classmethod
    def load(cls, folder: Path) -> "TrainedModel":
        state = torch.load(folder / "model.pt", map_location="cpu", weights_only=True)
        return cls(state["model"], state["skybox"], state["touched"], load_json(folder, "train_log.json"))


@dataclass(frozen=True)
class TrainingPlan:
    """How long training runs; frozen, written only by ``stages/plan.py``. Known after the teacher
    (``plan_limits``): ``time_budget_s`` (training's cap in seconds; None: configured steps run to the end),
    ``samples_per_step`` (pixels per batch), measured ``steps_per_second`` (None with configured steps),
    ``configured_steps``, ``max_steps`` (what the cap affords) and ``eval_seconds`` (the held-out evaluation's
    estimate, which a run budget keeps free). Fixed after the geometry (``fix_steps``): ``steps``,
    ``needed_steps`` (for the target samples per used texel), ``used_texels`` and the ``reason`` the report
    gives."""

    time_budget_s: float | None
    samples_per_step: int
    steps_per_second: float | None
    configured_steps: int | None
    max_steps: int = 0
    steps: int | None = None
    needed_steps: int | None = None
    used_texels: int | None = None
    reason: str | None = None
    eval_seconds: float | None = None

    def to_json(self) -> dict:
        return asdict(self)

    def save(self, folder: Path) -> None:
        save_json(folder, "plan.json", self.to_json())

    @classmethod
    def load(cls, folder: Path) -> "TrainingPlan":
        stored = load_json(folder, "plan.json")
        return cls(**{f.name: stored[f.name] for f in fields(cls) if f.name in stored})


@dataclass
class TrainingViews:
    """The training views as the distillation sees them: ``origin`` ((3,) float64 world position everything
    below is relative to), ``mesh`` (the unwrapped mesh relative to it, float32), ``gbuffer`` (per view
    (N, H, W, ...) uv, face_id, coverage, depth, normal) and ``dirs`` ((N, H, W, 3 or more) view inputs:
    world ray directions, reflected about the shading normal on covered pixels with ``ShaderInputs.reflect``,
    plus the facing cosine and the mesh layer when the shader takes them)."""

    origin: np.ndarray
    mesh: MeshData
    gbuffer: GBuffer
    dirs: np.ndarray


@dataclass
class Backdrop:
    """What the bundle shows where the mesh is not: the trained-to-be ``skybox`` (``SkyboxModel`` or None),
    the training cameras' positions relative to its layers (``sky_origins``, (N, 3), None without skyboxes),
    the ``reason`` of that choice, the ``clear`` colour ((3,) float32 tensor), and ``sky_pixels`` ((N, H, W)
    bool, the uncovered training pixels the skyboxes learn from; None: all of them)."""

    skybox: SkyboxModel | None
    sky_origins: np.ndarray | None
    reason: str
    clear: torch.Tensor
    sky_pixels: np.ndarray | None = None


@dataclass
class DistilledModel:
    """The distill stage's outcome: the trained ``model`` (``NeuralTextureModel``, eval mode), its ``skybox``
    (or None) and the training log (``TrainLog.as_dict()``)."""

    model: NeuralTextureModel
    skybox: SkyboxModel | None
    log: dict


@dataclass
class Evaluation:
    """The bundle measured against the field on the held-out cameras.

    Attributes:
        field_views: the field's held-out renders and their frame times; bundle_images: (H, W, 3) per view.
        quality: ``evaluate.compare`` (psnr, ssim, per view); parity: GL vs torch PSNR on view 0.
        fidelity: ``evaluate.fidelity`` (flip, interior/silhouette PSNR, holes, crops); flip_maps: per view;
        fidelity_seconds: its time. ablation: PSNR with and without skyboxes (None without them).
        timing: ``BundleRenderer.time_frames``; silhouette_blend: whether the player ran the soft-silhouette
        pass; plain: the plain-texture baseline; runtime_points: the field's
        error against run time; extrapolation and extra_views: lane-shifted views (None / {} without them);
        part_seconds: where the stage's time went.
    """

    field_views: FieldViews
    bundle_images: list
    quality: dict
    parity: float
    fidelity: dict
    flip_maps: list
    fidelity_seconds: float
    ablation: dict | None
    timing: dict
    silhouette_blend: bool
    plain: dict
    runtime_points: list
    extrapolation: dict | None
    extra_views: dict
    part_seconds: dict = field(default_factory=dict)
    """Wall seconds of the stage's parts (field views, bundle renders, parity, fidelity, timing, ...)."""
