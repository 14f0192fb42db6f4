"""A nerfstudio run folder: where its files are and what its ``config.yml`` says (docs/formats.md §3).

This module owns :func:`find_run` (a ``config.yml``, its run folder or a checkpoint inside it -> the config, the
newest ``nerfstudio_models/step-*.ckpt``, ``dataparser_transforms.json``, which must be there) and
:func:`nerfacto_settings` (the model section of ``config.yml`` -> :class:`NerfactoSettings`, with the defaults of
the nerfstudio versions that lacked a key). ``config.yml`` is read with ``!!python/...`` tags as data
(``adapters.yaml_text``): nothing in it is imported or run.

Supported methods: those whose field is nerfstudio's ``NerfactoField``: nerfacto, nerfacto-big, nerfacto-huge,
depth-nerfacto (the model section's ``_type`` is ``NerfactoModelConfig`` or ``DepthNerfactoModelConfig``).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from neuras_distill.errors import BadInputError, require
from neuras_distill.render.far_region import FarRegion

from ..yaml_text import load_yaml

#: Methods whose field is nerfstudio's NerfactoField (method_name -> what differs).
SUPPORTED_METHODS = ("nerfacto", "nerfacto-big", "nerfacto-huge", "depth-nerfacto")
_MODEL_TYPES = ("NerfactoModelConfig", "DepthNerfactoModelConfig")
_STEP_RE = re.compile(r"^step-(\d+)\.ckpt$")


@dataclass
class NerfstudioRun:
    """The files of one run: ``config`` (the parsed config.yml), ``checkpoint`` (the newest step-*.ckpt),
    ``dataparser`` (``{"transform": (3, 4), "scale": float}``), ``folder``."""

    folder: Path
    config_path: Path
    config: dict
    checkpoint: Path
    dataparser: dict


@dataclass
class NerfactoSettings:
    """The NerfactoField's hyper-parameters as the model section sets them (nerfstudio 1.1 names), the camera
    optimizer's mode and the data parser's split (``(eval_mode, eval_interval, train_split_fraction)``).

    The field's own defaults apply to what the model config does not pass (``num_layers`` 2, ``num_layers_color``
    3, ``geo_feat_dim`` 15). Keys older configs lack take the value those versions used: ``implementation``
    "tcnn" (before 0.1.16 there was no torch choice), ``average_init_density`` 1.0 (before 1.0 the density was
    ``exp(h)`` unscaled), ``appearance_embed_dim`` 32, ``use_appearance_embedding`` True."""

    method: str = "nerfacto"
    num_levels: int = 16
    base_res: int = 16
    max_res: int = 2048
    log2_hashmap_size: int = 19
    features_per_level: int = 2
    hidden_dim: int = 64
    hidden_dim_color: int = 64
    num_layers: int = 2
    num_layers_color: int = 3
    geo_feat_dim: int = 15
    appearance_embed_dim: int = 32
    use_appearance_embedding: bool = True
    use_average_appearance_embedding: bool = True
    average_init_density: float = 1.0
    implementation: str = "tcnn"
    disable_scene_contraction: bool = False
    background_color: str = "last_sample"
    near_plane: float = 0.05
    far_plane: float = 1000.0
    scene_scale: float = 1.0
    camera_optimizer: str = "off"
    split: tuple = ("fraction", 8, 0.9)
    notes: list = field(default_factory=list)


def find_run(path) -> NerfstudioRun:
    """The run behind ``path``: its ``config.yml``, the folder holding it, or a ``.ckpt`` inside the run."""
    path = Path(path)
    require(path.exists(), f"{path} does not exist; give a nerfstudio run's config.yml "
                           "(outputs/<scene>/<method>/<timestamp>/config.yml) or its folder")
    if path.is_dir():
        folder, config_path = path, path / "config.yml"
    elif path.suffix == ".ckpt":
        folder = path.parent.parent if path.parent.name == "nerfstudio_models" else path.parent
        config_path = folder / "config.yml"
    else:
        folder, config_path = path.parent, path
    require(config_path.is_file(), f"{folder} has no config.yml; give the run folder nerfstudio wrote "
                                   "(outputs/<scene>/<method>/<timestamp>)")
    config = read_config(config_path)
    models = folder / "nerfstudio_models"
    if path.suffix == ".ckpt":
        checkpoint = path
    else:
        steps = sorted((int(m.group(1)), p) for p in (models.glob("step-*.ckpt") if models.is_dir() else [])
                       if (m := _STEP_RE.match(p.name)))
        require(bool(steps), f"{folder} has no checkpoint (nerfstudio_models/step-*.ckpt); training saves one "
                             "every steps_per_save steps: let it run that long, or give the folder that has one")
        checkpoint = steps[-1][1]
    dataparser = read_dataparser_transforms(folder / "dataparser_transforms.json")
    require(dataparser is not None,
            f"{folder} has no dataparser_transforms.json: without it the field's frame, scale and far plane "
            "cannot be placed against the dataset's cameras; nerfstudio writes it beside config.yml when training "
            "starts: copy it from the run folder")
    return NerfstudioRun(folder, config_path, config, checkpoint, dataparser)


def _named_dataset(config: dict) -> str | None:
    """The dataset path config.yml names (the data manager's ``data``, else the trainer's, else the data parser's
    own when it is not ``.``), as written; None when it names none."""
    datamanager = (config.get("pipeline") or {}).get("datamanager") or {}
    for value in (datamanager.get("data"), config.get("data"), (datamanager.get("dataparser") or {}).get("data")):
        if isinstance(value, str) and value.strip() not in ("", "."):
            return re.sub(r"^/+", "/", value.strip())
    return None


def dataset_transforms(run: NerfstudioRun, cwd: Path | None = None) -> tuple[Path | None, str]:
    """(the dataset's ``transforms.json``, what was looked at) for a run without ``--cameras``.

    Where nerfstudio looks: the ``data`` path config.yml names, a folder holding ``transforms.json`` or that file
    itself; a relative path is relative to where ``ns-train`` ran, which is ``cwd`` (default: the current folder)
    or the folder holding ``outputs/`` (the run folder's ancestors are tried). A run moved away from its dataset
    (copied from another machine) is also looked for beside ``config.yml``. None with the reason when nothing is
    found."""
    named = _named_dataset(run.config)
    candidates: list[Path] = []
    if named is not None:
        path = Path(named)
        candidates += [path] if path.is_absolute() else [(cwd or Path.cwd()) / path,
                                                         *(base / path for base in run.folder.resolve().parents)]
    candidates.append(run.folder)
    for candidate in candidates:
        found = candidate if candidate.suffix == ".json" else candidate / "transforms.json"
        if found.is_file():
            how = ("the dataset config.yml names" if candidate is not run.folder
                   else f"beside config.yml (the dataset config.yml names, {named}, is not here)" if named
                   else "beside config.yml")
            return found, how
    where = f"the dataset config.yml names ({named}) has no transforms.json here" if named \
        else "config.yml names no dataset"
    return None, where


def read_config(path: Path) -> dict:
    """config.yml as plain data (tags as data, nothing run); refuses a file that is not a nerfstudio config."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{path} cannot be read as text: {exc}") from None
    data = load_yaml(text, str(path), python_tags=True)
    require(isinstance(data, dict) and "pipeline" in data and "method_name" in data,
            f"{path} is not a nerfstudio config.yml (no method_name / pipeline); give the config.yml nerfstudio "
            "wrote next to nerfstudio_models/")
    return data


def nerfacto_settings(config: dict, source: str = "config.yml") -> NerfactoSettings:
    """:class:`NerfactoSettings` from a parsed config.yml; refuses methods whose field is not NerfactoField."""
    method = str(config.get("method_name", "?"))
    model = (config.get("pipeline") or {}).get("model") or {}
    kind = str(model.get("_type", "")).rsplit(".", 1)[-1]
    require(method in SUPPORTED_METHODS or kind in _MODEL_TYPES,
            f"{source}: method {method!r} ({kind or 'no model type'}) is not supported; supported: "
            f"{', '.join(SUPPORTED_METHODS)} (nerfstudio's nerfacto field). Splatfacto and other methods are "
            "not NeRF fields this adapter reads")
    out = NerfactoSettings(method=method)
    for name in ("num_levels", "base_res", "max_res", "log2_hashmap_size", "features_per_level", "hidden_dim",
                 "hidden_dim_color", "appearance_embed_dim"):
        if name in model:
            setattr(out, name, _int(model[name], name, source))
    for name in ("use_appearance_embedding", "use_average_appearance_embedding", "disable_scene_contraction"):
        if name in model:
            setattr(out, name, bool(model[name]))
    for name in ("average_init_density", "near_plane", "far_plane"):
        if name in model:
            setattr(out, name, float(model[name]))
    FarRegion(near=out.near_plane, far=out.far_plane, pivot=1.0)     # the collider's planes, nerfstudio units
    for name, default in (("implementation", "tcnn"), ("average_init_density", 1.0)):
        if name not in model:
            out.notes.append(f"config has no {name} (an older nerfstudio): {default!r} as that version used")
    if "implementation" in model:
        out.implementation = str(model["implementation"])
        require(out.implementation in ("tcnn", "torch"),
                f"{source}: implementation {out.implementation!r} is neither 'tcnn' nor 'torch'")
    if "background_color" in model:
        out.background_color = str(model["background_color"])
    datamanager = (config.get("pipeline") or {}).get("datamanager") or {}
    parser = datamanager.get("dataparser") or {}
    if "scene_scale" in parser:
        out.scene_scale = float(parser["scene_scale"])
    # the camera optimizer (the model's since nerfstudio 1.0, the data manager's before) and the data parser's
    # train / eval split, which numbers its pose corrections
    optimizer = model.get("camera_optimizer") or datamanager.get("camera_optimizer") or {}
    out.camera_optimizer = str(optimizer.get("mode", "off")) if isinstance(optimizer, dict) else "off"
    out.split = (str(parser.get("eval_mode", "fraction")), int(parser.get("eval_interval", 8) or 8),
                 float(parser.get("train_split_fraction", 0.9)))
    return out


def _int(value, name: str, source: str) -> int:
    require(isinstance(value, int) and not isinstance(value, bool) and value > 0,
            f"{source}: model.{name} must be a positive integer, got {value!r}")
    return int(value)


def read_dataparser_transforms(path: Path) -> dict | None:
    """``dataparser_transforms.json`` -> ``{"transform": (3, 4) float64, "scale": float}``, None when absent."""
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
        transform = np.asarray(data["transform"], dtype=np.float64)
        scale = float(data["scale"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BadInputError(f"{path} is not a nerfstudio dataparser_transforms.json ({exc}); remove it to use "
                            "nerfstudio's own frame, or restore the file training wrote") from None
    require(transform.shape == (3, 4) and bool(np.isfinite(transform).all()),
            f"{path}: transform must be a finite 3x4 matrix, got shape {transform.shape}")
    require(np.isfinite(scale) and scale > 0, f"{path}: scale must be a positive number, got {scale}")
    rot = transform[:, :3]
    require(bool(np.allclose(rot @ rot.T, np.eye(3), atol=1e-4)),
            f"{path}: the transform's 3x3 part is not a rotation; the file is damaged")
    return {"transform": transform, "scale": scale}
