"""NeuS-family checkpoint files to fields: :func:`load_neus_checkpoint` (the adapter's ``load``).

Tells Totoro97/NeuS (``sdf_network_fine``) from instant-nsr-pl (a Lightning ``state_dict`` with the hash grid
or ``variance.variance``) by the loaded keys (:func:`detect_form`), reads the cameras (``cameras_sphere.npz``,
whose scale matrix places the field in the world, or ``transforms.json``), builds
:class:`~.mlp_field.NeuSField` or :class:`~.hashgrid_field.HashGridNeuSField`, and optionally wraps it in a
VolSDF Laplace density (:func:`with_density`, docs/formats.md §2.4). The checkpoint itself is read by
:func:`neuras_distill.fields.checkpoint.load_torch_checkpoint` (weights only, never unpickling code).
"""

from __future__ import annotations

import math
from pathlib import Path

from neuras_distill.errors import BadInputError, require

from .base import DEFAULT_CHUNK
from .hashgrid_field import HashGridNeuSField
from .mlp_field import NeuSField
from .nsr_config import read_nsr_config


def detect_form(ckpt: dict) -> str | None:
    """``"neus"``, ``"nsr"`` or None from a loaded checkpoint's keys."""
    if "sdf_network_fine" in ckpt:
        return "neus"
    sd = ckpt.get("state_dict")
    if isinstance(sd, dict) and any(isinstance(k, str) and k.endswith("geometry.encoding.encoding.params")
                                    or k in ("model.variance.variance", "variance.variance") for k in sd):
        return "nsr"
    return None


def _read_cameras(cameras, width, height, nsr_cfg: dict | None):
    """(Cameras or None, scale_mat or None) from a camera-file path (npz or transforms.json) or Cameras."""
    from neuras_distill.render.cameras import Cameras

    from .cameras import cameras_from_neus_npz

    if cameras is None:
        return None, None
    if isinstance(cameras, Cameras):
        return cameras, None
    path = Path(cameras)
    require(path.is_file(), f"camera file {path} does not exist" if not path.exists() else
            f"camera file {path} is a directory; give cameras_sphere.npz or transforms.json")
    with open(path, "rb") as fh:
        head = fh.read(4)
    if head.startswith(b"PK"):  # npz = zip
        if (width is None or height is None) and nsr_cfg is not None:
            wh = (nsr_cfg.get("dataset") or {}).get("img_wh")
            if isinstance(wh, (list, tuple)) and len(wh) == 2:
                width = wh[0] if width is None else width
                height = wh[1] if height is None else height
        return cameras_from_neus_npz(path, width, height)
    return Cameras.from_transforms(path), None


def with_density(field, density: str = "neus", beta: float | None = None):
    """``field`` itself (``density="neus"``) or its VolSDF Laplace density view (``"laplace"``, kind
    ``"density"``) with ``beta`` in world units (default ``1 / field.inv_s``: the NeuS ramp's width)."""
    from neuras_distill.fields.wrappers import SDFToDensityField

    require(density in ("neus", "laplace"), f"density must be 'neus' or 'laplace', got {density!r}")
    if density == "neus":
        return field
    beta = 1.0 / float(field.inv_s) if beta is None else float(beta)
    require(beta > 0 and math.isfinite(beta), f"beta must be positive and finite, got {beta}")
    return SDFToDensityField(field, beta)


def load_neus_checkpoint(path, *, cameras=None, config=None, density: str = "neus", width: int | None = None,
                         height: int | None = None, beta: float | None = None, scale_mat=None,
                         background_color=None, bound: str = "sphere", sdf_scale: float = 1.0,
                         chunk: int | None = DEFAULT_CHUNK):
    """Load a NeuS (``.pth``) or instant-nsr-pl (``.ckpt``) checkpoint as a world-frame field.

    Args:
        cameras: path of ``cameras_sphere.npz`` (its scale matrix places the field in the world and its
            cameras are attached) or of a ``transforms.json`` (cameras attached, network frame = world),
            or a :class:`Cameras`; None: network frame = world, no cameras.
        config: instant-nsr-pl only: dict or path of ``parsed.yaml``/JSON (defaults: neus-blender).
        density: ``"neus"`` (kind "sdf", NeuS opacity from ``inv_s``) or ``"laplace"`` (kind "density",
            VolSDF σ with ``beta``).
        width, height: training image size for ``cameras_sphere.npz`` (not stored in it).
        scale_mat: explicit (4, 4) network-to-world similarity (overrides the npz's).
        background_color: (3,), default white. bound, sdf_scale: NeuS only (see :class:`~.mlp_field.NeuSField`).
    """
    from neuras_distill.fields.checkpoint import load_torch_checkpoint

    ckpt = load_torch_checkpoint(path)
    form = detect_form(ckpt)
    if form is None:
        keys = ", ".join(sorted(str(k) for k in ckpt)[:8])
        raise BadInputError(f"{path} is not a NeuS checkpoint (no 'sdf_network_fine') nor an instant-nsr-pl one "
                            f"(no state_dict with 'model.geometry.encoding.encoding.params'); top-level keys: {keys}")
    if form == "neus":
        require(config is None, "config= is for instant-nsr-pl checkpoints; a NeuS checkpoint needs none")
    nsr_cfg = read_nsr_config(config) if (form == "nsr" and config is not None) else None
    cams, npz_scale = _read_cameras(cameras, width, height, nsr_cfg)
    scale = scale_mat if scale_mat is not None else npz_scale
    source = str(path)
    if form == "neus":
        field = NeuSField(ckpt, scale_mat=scale, sdf_scale=sdf_scale, background_color=background_color,
                          cameras=cams, bound=bound, chunk=chunk, source=source)
    else:
        field = HashGridNeuSField(ckpt["state_dict"], nsr_cfg, scale_mat=scale, background_color=background_color,
                                  cameras=cams, chunk=chunk, source=source)
    return with_density(field, density, beta)
