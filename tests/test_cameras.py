"""Cameras: transforms.json parsing, validation of bad poses/intrinsics, rays through pixel centres."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from neuras_distill.errors import BadInputError
from neuras_distill.render.cameras import Cameras


def test_from_transforms_reads_the_fox(fox_transforms):
    notes = []
    cams = Cameras.from_transforms(fox_transforms, warn=notes.append)
    meta = json.loads(fox_transforms.read_text())
    assert len(cams) == 67
    assert (cams.width, cams.height) == (1080, 1920)
    assert float(cams.fx[0]) == pytest.approx(1375.52)
    assert float(cams.fy[0]) == pytest.approx(1374.49)
    assert float(cams.cx[0]) == pytest.approx(554.558)
    assert float(cams.cy[3]) == pytest.approx(965.268)
    first = np.array(meta["frames"][0]["transform_matrix"])
    assert np.allclose(cams.c2w[0].numpy(), first, atol=1e-6)
    assert any("distortion" in n and "k1" in n for n in notes)


def test_camera_angle_gives_focal(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"camera_angle_x": math.radians(90), "w": 200, "h": 100,
                                "frames": [{"transform_matrix": np.eye(4).tolist()}]}))
    cams = Cameras.from_transforms(path)
    assert float(cams.fx[0]) == pytest.approx(100.0)
    assert float(cams.fy[0]) == pytest.approx(100.0)
    assert float(cams.cx[0]) == pytest.approx(100.0) and float(cams.cy[0]) == pytest.approx(50.0)


def test_per_frame_overrides(tmp_path):
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"fl_x": 50, "w": 64, "h": 48, "frames": [
        {"transform_matrix": np.eye(4).tolist()}, {"transform_matrix": np.eye(4).tolist(), "fl_x": 80}]}))
    cams = Cameras.from_transforms(path)
    assert cams.fx.tolist() == [50.0, 80.0]
    assert cams.fy.tolist() == [50.0, 80.0]


@pytest.mark.parametrize("frame_change, message", [
    ({"fl_x": 0.0}, "focal length"),
    ({"fl_x": -5.0}, "focal length"),
    ({"transform_matrix": [[float("nan")] * 4] * 4}, "NaN"),
    ({"transform_matrix": (np.diag([2.0, 1.0, 1.0, 1.0])).tolist()}, "not rigid"),
    ({"transform_matrix": (np.diag([-1.0, 1.0, 1.0, 1.0])).tolist()}, "reflection"),
])
def test_bad_cameras_are_rejected(tmp_path, frame_change, message):
    frame = {"transform_matrix": np.eye(4).tolist(), "fl_x": 50.0}
    frame.update(frame_change)
    path = tmp_path / "t.json"
    path.write_text(json.dumps({"w": 64, "h": 48, "frames": [frame]}))
    with pytest.raises(BadInputError, match=message):
        Cameras.from_transforms(path)


def test_no_cameras_and_bad_files(tmp_path):
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"w": 4, "h": 4, "fl_x": 3, "frames": []}))
    with pytest.raises(BadInputError, match="no cameras"):
        Cameras.from_transforms(empty)
    garbage = tmp_path / "garbage.json"
    garbage.write_bytes(b"\x00\xffnot json")
    with pytest.raises(BadInputError, match="not valid JSON"):
        Cameras.from_transforms(garbage)
    with pytest.raises(BadInputError, match="does not exist"):
        Cameras.from_transforms(tmp_path / "missing.json")
    with pytest.raises(BadInputError, match="directory"):
        Cameras.from_transforms(tmp_path)
    with pytest.raises(BadInputError, match="no cameras"):
        Cameras(torch.zeros(0, 4, 4), [], [], [], [], 4, 4)


def test_rays_go_through_pixel_centres():
    c2w = torch.eye(4)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, 3.0])
    cams = Cameras(c2w, 10.0, 20.0, 4.0, 3.0, 8, 6)
    o, d = cams.rays(0)
    assert o.shape == (6, 8, 3) and torch.allclose(o[0, 0], torch.tensor([1.0, 2.0, 3.0]))
    assert torch.allclose(d.norm(dim=-1), torch.ones(6, 8), atol=1e-6)
    # Pixel (u=5, v=1): x = (5.5 - 4) / 10 = 0.15, y = -(1.5 - 3) / 20 = 0.075, z = -1
    expected = torch.tensor([0.15, 0.075, -1.0])
    assert torch.allclose(d[1, 5], expected / expected.norm(), atol=1e-6)


def test_orbit_looks_at_centre_and_split():
    cams = Cameras.orbit([0.5, -1.0, 2.0], 4.0, 16, width=64, height=48, elevation_deg=(10, 40))
    assert len(cams) == 16 and (cams.width, cams.height) == (64, 48)
    dist = (cams.centers - torch.tensor([0.5, -1.0, 2.0])).norm(dim=-1)
    assert torch.allclose(dist, torch.full((16,), 4.0), atol=1e-4)
    forward = -cams.c2w[:, :3, 2]
    to_centre = torch.nn.functional.normalize(torch.tensor([0.5, -1.0, 2.0]) - cams.centers, dim=-1)
    assert torch.allclose((forward * to_centre).sum(-1), torch.ones(16), atol=1e-5)
    train, test = cams.split(8)
    assert len(test) == 2 and len(train) == 14
    assert not set(test.centers[:, 0].tolist()) & set(train.centers[:, 0].tolist())


def test_resized_keeps_field_of_view():
    cams = Cameras.orbit([0, 0, 0], 3.0, 2, width=400, height=200, fov_deg=60)
    small = cams.resized(100)
    assert (small.width, small.height) == (100, 50)
    fov = 2 * math.degrees(math.atan(0.5 * small.width / float(small.fx[0])))
    assert fov == pytest.approx(60.0, abs=1e-4)


def test_json_round_trip():
    cams = Cameras.orbit([0, 0, 0], 3.0, 3, width=40, height=30)
    back = Cameras.from_json(json.loads(json.dumps(cams.to_json())))
    assert torch.allclose(back.c2w, cams.c2w) and torch.allclose(back.fx, cams.fx)
