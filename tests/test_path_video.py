"""``neuras-distill render``: nerfstudio camera paths and orbits as MP4 or PNG frames, the field beside the bundle,
and the frame a path is put in."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from neuras_distill.cli import main
from neuras_distill.render.camera_path import (
    camera_path_json,
    from_dataset_frame,
    read_camera_path,
    to_dataset_frame,
)

pytestmark = pytest.mark.gl


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 10.0 * np.log10(255.0 ** 2 / max(mse, 1e-12))


def _decoded(path) -> list[np.ndarray]:
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        return [f.to_ndarray(format="rgb24") for f in container.decode(stream)]


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory):
    """A run the command line made (so --compare can load its field again): the sphere, fast preset."""
    out = tmp_path_factory.mktemp("video") / "sphere"
    assert main(["from-synthetic", "sphere", "--preset", "fast", "--eval-width", "160", "--steps", "200",
                 "--out", str(out), "--quiet"]) == 0
    return out


def _orbit_path(run, tmp_path, seconds: float, fps: float, size=(160, 90)):
    """A camera_path.json in nerfstudio's format of an orbit around the run's bundle, in the bundle's frame."""
    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.viewer import world_orbit_cameras

    cams = world_orbit_cameras(load_bundle(run / "bundle"), round(seconds * fps), *size)
    path = tmp_path / "camera_path.json"
    path.write_text(json.dumps(camera_path_json(cams, fps)))
    return path, cams


def test_a_ten_second_mp4_along_a_camera_path_shows_what_the_player_draws(cli_run, tmp_path, capsys):
    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.renderer import BundleRenderer

    path, cams = _orbit_path(cli_run, tmp_path, seconds=10.0, fps=24.0, size=(320, 180))
    video = tmp_path / "orbit.mp4"
    assert main(["render", str(cli_run / "bundle"), "--camera-path", str(path), "--out", str(video)]) == 0
    said = capsys.readouterr()
    assert "in the bundle's own frame" in said.err and "240 frames" in said.out
    frames = _decoded(video)
    assert len(frames) == 240 and frames[0].shape == (180, 320, 3)
    with BundleRenderer(load_bundle(cli_run / "bundle")) as player:
        scores = [_psnr(frames[i], np.round(np.clip(player.render(cams, i), 0, 1) * 255)) for i in range(0, 240, 24)]
    assert min(scores) >= 40.0, scores
    assert not list(tmp_path.glob(".*partial*"))


def test_compare_puts_the_field_beside_the_bundle_from_the_run_folder(cli_run, tmp_path):
    path, cams = _orbit_path(cli_run, tmp_path, seconds=0.25, fps=12.0, size=(64, 36))
    out = tmp_path / "frames"
    assert main(["render", str(cli_run), "--camera-path", str(path), "--compare", str(cli_run), "--out",
                 str(out)]) == 0
    from PIL import Image

    pngs = sorted(out.glob("frame_*.png"))
    assert len(pngs) == 3
    img = np.asarray(Image.open(pngs[0]))
    assert img.shape == (36, 2 * 64 + 4, 3)
    field, bundle = img[:, :64].astype(float), img[:, 68:].astype(float)
    assert _psnr(field, bundle) > 20.0           # the same sphere, seen from the same camera
    assert np.abs(field - bundle).mean() > 0.0   # and two pictures, not one copied


def test_orbit_frames_as_png(cli_run, tmp_path):
    out = tmp_path / "orbit"
    assert main(["render", str(cli_run / "bundle"), "--orbit", "4", "--width", "64", "--height", "48",
                 "--out", str(out)]) == 0
    assert len(list(out.glob("frame_*.png"))) == 4


def test_a_nerfstudio_path_is_put_in_the_dataset_frame_by_the_dataparser_transform():
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    frame = {"transform": np.concatenate([rot, rng.normal(size=(3, 1))], 1).tolist(), "scale": 0.37}
    c2w = np.tile(np.eye(4), (3, 1, 1))
    c2w[:, :3, 3] = rng.normal(size=(3, 3))
    ns = from_dataset_frame(c2w, frame)
    # x_ns = s (R x + t) for the camera centres, and the axes turned by R
    expected = 0.37 * (c2w[:, :3, 3] @ rot.T + np.asarray(frame["transform"])[:, 3])
    np.testing.assert_allclose(ns[:, :3, 3], expected, atol=1e-12)
    np.testing.assert_allclose(ns[:, :3, :3], rot[None] @ c2w[:, :3, :3], atol=1e-12)
    np.testing.assert_allclose(to_dataset_frame(ns, frame), c2w, atol=1e-12)


def test_the_nerfstudio_fixture_records_its_viewer_frame():
    from neuras_distill.stability.source import load_source

    field, _ = load_source("tests/data/nerfstudio/orbit360/config.yml")
    dp = json.loads(open("tests/data/nerfstudio/orbit360/dataparser_transforms.json").read())
    frame = field.viewer_frame()
    np.testing.assert_allclose(frame["transform"], dp["transform"])
    assert frame["scale"] == pytest.approx(dp["scale"])


def test_a_path_read_back_has_nerfstudios_focal_length(tmp_path):
    data = {"render_width": 200, "render_height": 100, "fps": 30, "camera_path": [
        {"camera_to_world": np.eye(4).reshape(-1).tolist(), "fov": 90.0, "aspect": 2.0}]}
    (tmp_path / "p.json").write_text(json.dumps(data))
    path = read_camera_path(tmp_path / "p.json")
    cams = path.cameras()
    assert float(cams.fy[0]) == pytest.approx(50.0) and float(cams.fx[0]) == pytest.approx(50.0)
    assert (float(cams.cx[0]), float(cams.cy[0])) == (100.0, 50.0) and path.fps == 30.0


@pytest.mark.parametrize("content,fragment", [
    ("not json", "is not JSON"),
    (json.dumps({"frames": [], "camera_angle_x": 0.7}), "is a transforms.json"),
    (json.dumps({"keyframes": []}), "has no \"camera_path\" list"),
    (json.dumps({"render_width": 64, "render_height": 36, "camera_path": [{"camera_to_world": [1, 2], "fov": 50}]}),
     "16 finite numbers"),
    (json.dumps({"render_width": 64, "render_height": 36, "camera_type": "equirectangular",
                 "camera_path": [{"camera_to_world": np.eye(4).reshape(-1).tolist(), "fov": 50}]}),
     "is not supported"),
])
def test_a_malformed_or_foreign_camera_path_is_one_line_and_writes_nothing(cli_run, tmp_path, capsys, content,
                                                                            fragment):
    bad = tmp_path / "camera_path.json"
    bad.write_text(content)
    out = tmp_path / "video.mp4"
    assert main(["render", str(cli_run / "bundle"), "--camera-path", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("neuras-distill: error:") and fragment in err[0], err
    assert not out.exists() and not list(tmp_path.glob(".*partial*"))


def test_a_nerfstudio_run_without_its_dataparser_transform_cannot_take_a_nerfstudio_path(cli_run, tmp_path, capsys):
    run = tmp_path / "ns-run"
    shutil.copytree(cli_run, run, ignore=shutil.ignore_patterns("work"))
    report = json.loads((run / "report.json").read_text())
    report["source"]["command"] = ["neuras-distill", "from-nerfstudio", "outputs/x/nerfacto/1/config.yml"]
    report["field"].pop("viewer_frame", None)
    (run / "report.json").write_text(json.dumps(report))
    path, _ = _orbit_path(cli_run, tmp_path, seconds=0.25, fps=4.0, size=(32, 18))
    out = tmp_path / "video.mp4"
    assert main(["render", str(run), "--camera-path", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot be put in the bundle's frame" in err[0] and "--dataparser-transforms" in err[0]
    assert not out.exists()
    # told that the path is in the bundle's own frame, it plays
    assert main(["render", str(run), "--camera-path", str(path), "--path-frame", "bundle", "--out", str(out)]) == 0
    assert out.is_file()
