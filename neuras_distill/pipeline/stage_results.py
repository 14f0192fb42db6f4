"""What the expensive stages hand on, as small typed results that the work area stores and reuses
(:class:`pipeline.cache.StageCache`): each has ``save(folder)`` and ``load(folder)``.

Frames: teacher and held-out renders are per camera, row 0 at the top of the image; meshes are in world
coordinates; G-buffers are rasterized relative to the run's origin (``pipeline.run``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..geometry.mesh import MeshData
from ..playback.gbuffer import GBuffer
from .cache import load_arrays, load_json, save_arrays, save_json


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

    def save(self, folder: Path) -> None:
        save_arrays(folder, images=self.images, opacities=self.opacities, surface_depths=self.surface_depths,
                    fringe_depths=self.fringe_depths)
        save_json(folder, "teacher.json", {"seconds": self.seconds})

    @classmethod
    def load(cls, folder: Path) -> "TeacherResult":
        arrays = load_arrays(folder, "images", "opacities", "surface_depths", "fringe_depths")
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


def save_gbuffer(gbuffer: GBuffer, folder: Path) -> None:
    """One memory-mappable ``.npy`` per attribute."""
    arrays = {"uv": gbuffer.uv, "face_id": gbuffer.face_id, "coverage": gbuffer.coverage, "depth": gbuffer.depth}
    if gbuffer.normal is not None:
        arrays["normal"] = gbuffer.normal
    save_arrays(folder, **arrays)


def load_gbuffer(folder: Path, mmap: bool = False) -> GBuffer:
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
