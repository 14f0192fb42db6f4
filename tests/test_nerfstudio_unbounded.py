"""An unbounded nerfacto run made by nerfstudio's own trainer: the teacher against nerfstudio's own renders on
whole frames, inside the foreground box and outside it, and the camera optimizer's corrections.

The fixture ``tests/data/nerfstudio/orbit360`` was made by ``scripts/make_nerfstudio_unbounded_fixture.py``
(nerfstudio 1.1.5's ``ns-train`` code path on a closed-form 360-degree scene: objects on a ground plane that
reaches a distant skyline, a sky gradient; its ``reference_renders.npz`` are nerfstudio's renders of the held-out
views).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from neuras_distill.config import TeacherConfig
from neuras_distill.registry import load_field
from neuras_distill.render.cameras import Cameras
from neuras_distill.render.volume import VolumeRenderer

RUN = Path(__file__).parent / "data" / "nerfstudio" / "orbit360"


@pytest.fixture(scope="module")
def orbit():
    field = load_field(RUN / "config.yml")
    ref = np.load(RUN / "reference_renders.npz")
    rgb = ref["rgb"].astype(np.float32) / 255.0
    n, h, w, _ = rgb.shape
    f = float(ref["focal"])
    cams = Cameras(torch.from_numpy(ref["c2w"]).float(), f, f, w / 2, h / 2, w, h)
    return field, cams, rgb, [str(x) for x in ref["names"]]


def _psnr(a, b, mask=None):
    err = (a - b) ** 2
    err = err[mask] if mask is not None else err
    return -10.0 * math.log10(max(float(err.mean()), 1e-12))


@pytest.mark.slow
def test_the_run_is_unbounded_and_its_far_plane_is_nerfstudios(orbit):
    field, *_ = orbit
    config = (RUN / "config.yml").read_text()
    assert field.unbounded and field.far_region is not None
    scale = json.loads((RUN / "dataparser_transforms.json").read_text())["scale"]
    assert field.far_region.far == pytest.approx(1000.0 / scale)
    assert field.far_region.near == pytest.approx(0.05 / scale)
    assert "far_plane: 1000.0" in config


@pytest.mark.slow
def test_the_teacher_draws_nerfstudios_picture_inside_and_outside_the_box(orbit):
    """Two held-out views, every third pixel of each row and column over the whole frame (the CPU renders the
    far region at about a minute a full 160x120 view): the far region brings the ground, the skyline and the
    sky that a renderer clipped to the box leaves to the background colour."""
    field, cams, rgb, _ = orbit
    teacher = TeacherConfig()
    whole = VolumeRenderer(field, num_steps=teacher.num_steps, far_steps=teacher.far_steps,
                           occupancy_resolution=64)     # the far region needs no grid; 8x faster to build
    boxed = VolumeRenderer(field, num_steps=teacher.num_steps, far_steps=0, occupancy=whole.occupancy)
    img, clipped, ref, opacity = [], [], [], []
    for i in (0, 3):
        origins, dirs = cams.rays(i)
        o, d = origins[::3, ::3].reshape(-1, 3), dirs[::3, ::3].reshape(-1, 3)
        out = whole.render_rays(o, d)
        img.append(out["rgb"].numpy())
        opacity.append(out["opacity"].numpy())
        clipped.append(boxed.render_rays(o, d)["rgb"].numpy())
        ref.append(rgb[i][::3, ::3].reshape(-1, 3))
    img, clipped, ref = np.concatenate(img), np.concatenate(clipped), np.concatenate(ref)
    inside = np.concatenate(opacity) >= 0.5
    assert 0.05 < inside.mean() < 0.6, inside.mean()
    overall, outside, in_box = _psnr(img, ref), _psnr(img, ref, ~inside), _psnr(img, ref, inside)
    box_only = _psnr(clipped, ref, ~inside)
    print(f"teacher vs nerfstudio: {overall:.2f} dB, inside {in_box:.2f}, outside {outside:.2f}; box only: "
          f"outside {box_only:.2f}")
    assert overall >= 40.0 and outside >= 40.0 and in_box >= 40.0
    assert box_only < 25.0


@pytest.mark.slow
def test_the_camera_optimizers_corrections_move_the_training_cameras_only(orbit):
    field, cams, _, names = orbit
    meta = json.loads((RUN / "transforms.json").read_text())
    all_names = [f["file_path"] for f in meta["frames"]]
    dataset = Cameras.from_transforms(RUN / "transforms.json", warn=lambda m: None)
    corrected, count = field.corrected_cameras(dataset, all_names)
    held_out = [all_names.index(n) for n in names]
    assert count == len(all_names) - len(held_out) == field.pose_adjustment.shape[0]
    moved = (corrected.c2w - dataset.c2w).abs().amax(dim=(1, 2))
    assert bool((moved[held_out] == 0).all())
    assert float(moved.max()) > 0


def test_so3xr3_is_nerfstudios_exponential_map():
    from neuras_distill_adapters.nerfstudio.cameras import so3xr3

    axis, angle = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8]), 0.2
    rot, t = so3xr3(np.concatenate([[0.1, 0.2, 0.3], axis * angle])[None])
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rodrigues = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k
    assert np.allclose(rot[0], rodrigues, atol=1e-12) and np.allclose(t[0], [0.1, 0.2, 0.3])


def test_training_frames_are_numbered_as_nerfstudios_data_parser_numbers_them():
    from neuras_distill_adapters.nerfstudio.cameras import training_frame_indices

    names = [f"images/f{i:02d}.png" for i in (3, 0, 1, 2, 4, 5, 6, 7, 8, 9, 10)]
    interval = training_frame_indices(names, "interval", 5, 0.9)
    assert sorted(interval, key=interval.get) == [f"images/f{i:02d}.png" for i in (1, 2, 3, 4, 6, 7, 8, 9)]
    fraction = training_frame_indices(names, "fraction", 8, 0.9)     # ceil(11 * 0.9) = 10 of linspace(0, 10)
    assert len(fraction) == 10 and "images/f09.png" not in fraction
    assert training_frame_indices(names, "filename", 8, 0.9) == {}
