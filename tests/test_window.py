"""The window player (``neuras-distill view BUNDLE``, playback/window.py), its camera (camera_control.py) and its
view modes (view_modes.py).

The window tests run the real CLI in a subprocess under ``xvfb-run`` (Debian's xvfb: an X server without a
screen; GLX on Mesa's llvmpipe) and compare ``--screenshot`` (the window's framebuffer) with ``BundleRenderer``
for the same camera: the window blits the renderer's own frame 1:1, so the two must be the same picture. They skip
with the reason only where xvfb-run is absent (``.ci/run`` installs it).
"""

from __future__ import annotations

import ast
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.errors import BadInputError
from neuras_distill.metrics import psnr
from neuras_distill.playback.camera_control import CameraController, mean_up, pivot_distance, rotation_about
from neuras_distill.playback.view_modes import VIEW_MODES, mode_bundle
from neuras_distill.playback.window import camera_at, fit_to_screen
from neuras_distill.render.cameras import Cameras, look_at

XVFB_RUN = shutil.which("xvfb-run")
needs_gl = pytest.mark.gl  # tests/conftest.py: skipped without GL, failed under CI=true
needs_xvfb = pytest.mark.skipif(XVFB_RUN is None, reason="xvfb-run is not installed (apt-get install xvfb xauth); "
                                                         ".ci/run installs it")
pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ------------------------------------------------------------------------------------------ the camera
def _start_pose():
    import torch

    return look_at(torch.tensor([3.0, -2.0, 1.5]), torch.tensor([0.2, 0.1, 0.0]),
                   torch.tensor([0.0, 0.0, 1.0])).double().numpy()


def test_orbit_keeps_the_target_and_distance_and_reset_is_exact():
    pose = _start_pose()
    target = np.array([0.2, 0.1, 0.0])
    ctl = CameraController(pose, pivot_distance(pose, target, 1.0), world_up=(0, 0, 1))
    np.testing.assert_allclose(ctl.target, target, atol=1e-6)
    ctl.orbit(120.0, -40.0)
    np.testing.assert_allclose(ctl.target, target, atol=1e-6)          # turned about the target
    assert np.linalg.norm(ctl.eye - target) == pytest.approx(np.linalg.norm(pose[:3, 3] - target), rel=1e-7)
    assert not np.allclose(ctl.eye, pose[:3, 3])
    np.testing.assert_allclose(ctl.c2w[:3, :3].T @ ctl.c2w[:3, :3], np.eye(3), atol=1e-6)   # still a rotation
    assert abs(ctl.c2w[:3, 0] @ np.array([0, 0, 1.0])) < 1e-6          # no roll: right axis stays level
    ctl.zoom(3)
    ctl.fly(1.0, 0.5, 0.0, 0.2)
    ctl.reset()
    assert np.array_equal(ctl.c2w, pose) and ctl.pivot == pytest.approx(np.linalg.norm(pose[:3, 3] - target), rel=1e-6)


def test_orbit_stops_at_the_pole():
    pose = _start_pose()
    ctl = CameraController(pose, 3.0, world_up=(0, 0, 1))
    for _ in range(200):                                             # drag down for 200 x 50 px: far past 90 deg
        ctl.orbit(0.0, 50.0)
    assert abs(ctl.forward @ np.array([0, 0, 1.0])) < 0.996            # never looks straight down the up axis


def test_zoom_pan_fly_and_look():
    pose = _start_pose()
    ctl = CameraController(pose, 2.0, world_up=(0, 0, 1), speed=2.0)
    target = ctl.target
    ctl.zoom(2)                                                      # closer by 0.9^2, towards the same target
    assert ctl.pivot == pytest.approx(2.0 * 0.81)
    np.testing.assert_allclose(ctl.target, target, atol=1e-12)
    eye, right, up = ctl.eye, ctl.c2w[:3, 0].copy(), ctl.c2w[:3, 1].copy()
    ctl.pan(10.0, -4.0, fy=100.0)                                   # drag right/up: the scene follows the cursor
    step = ctl.pivot / 100.0
    np.testing.assert_allclose(ctl.eye - eye, -10.0 * step * right - 4.0 * step * up, atol=1e-12)
    eye, fwd = ctl.eye, ctl.forward
    ctl.fly(1.0, 0.0, 0.0, 0.25)                                     # W for a quarter second at 2 units/s
    np.testing.assert_allclose(ctl.eye - eye, 0.5 * fwd, atol=1e-12)
    eye = ctl.eye
    ctl.look(30.0, 0.0)
    np.testing.assert_allclose(ctl.eye, eye, atol=1e-12)             # looked around, did not move
    assert not np.allclose(ctl.forward, fwd)


def test_rotation_about_and_mean_up():
    r = rotation_about(np.array([0.0, 0.0, 2.0]), math.pi / 2)
    np.testing.assert_allclose(r @ np.array([1.0, 0, 0]), [0, 1.0, 0], atol=1e-12)
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, :3] = rotation_about(np.array([1.0, 0, 0]), 0.2)
    up = mean_up(poses)
    assert up @ np.array([0, 1.0, 0]) == pytest.approx(math.cos(0.1))    # halfway between the two up axes
    assert fit_to_screen(1920, 1080, (1280, 1024)) == pytest.approx(0.9 * 1280 / 1920)
    assert fit_to_screen(320, 240, (1280, 1024)) == 1.0


# ------------------------------------------------------------------------------------------ view modes
@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from test_web import _run_folder

    root = tmp_path_factory.mktemp("window_runs")
    out = {kind: _run_folder(root, kind) for kind in ("two-layer", "skybox")}
    bundle = load_bundle(out["skybox"][0])             # the skybox bundle with a plain texture added
    h, w = bundle.textures["u_index"].shape
    bundle.plain_rgb = np.random.default_rng(3).integers(0, 256, (h, w, 3), dtype=np.uint8)
    plain_run = root / "plain"
    bundle.save(plain_run / "bundle")
    shutil.copy(out["skybox"][0].parent / "cameras.json", plain_run / "cameras.json")
    out["plain"] = (plain_run / "bundle", out["skybox"][1])
    return out


def test_mode_bundle_refuses_unknown_modes_and_missing_plain_textures(runs):
    bundle = load_bundle(runs["two-layer"][0])
    with pytest.raises(BadInputError, match="unknown view mode"):
        mode_bundle(bundle, "normals")
    with pytest.raises(BadInputError, match="no plain texture"):
        mode_bundle(bundle, "plain")
    assert mode_bundle(bundle, "neural") is bundle
    assert list(VIEW_MODES) == ["neural", "plain", "uv", "index"]


def _index_colour(k: np.ndarray) -> np.ndarray:
    """The index mode's hash, on the CPU (uint32 arithmetic as in the GLSL)."""
    h = (k.astype(np.uint64) * 2654435761) & 0xFFFFFFFF
    h ^= h >> 15
    h = (h * 2246822519) & 0xFFFFFFFF
    h ^= h >> 13
    return np.stack([h & 255, (h >> 8) & 255, (h >> 16) & 255], -1).astype(np.uint8)


@needs_gl
def test_index_and_uv_modes_show_the_atlas(runs):
    from neuras_distill.playback.renderer import BundleRenderer

    bundle = load_bundle(runs["two-layer"][0])
    cams = runs["two-layer"][1]
    with BundleRenderer(mode_bundle(bundle, "index")) as r:
        img = np.round(r.render(cams, 0) * 255).astype(np.uint8)
    covered = np.any(img != np.round(bundle.background_color * 255).astype(np.uint8), axis=-1)
    assert covered.mean() > 0.05
    palette = {tuple(c) for c in _index_colour(np.unique(bundle.textures["u_index"]))}
    pixels = {tuple(c) for c in img[covered]}
    assert len(pixels & palette) / len(pixels) > 0.95          # (the silhouette pass blends a few edge pixels)
    with BundleRenderer(mode_bundle(bundle, "uv")) as r:
        uv_img = r.render(cams, 0)
    assert uv_img[covered].std(axis=0).min() > 0.02 and not np.allclose(uv_img, img / 255.0)


# ------------------------------------------------------------------------------------------ the window
def _view(bundle: Path, *args: str, env=None) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "neuras_distill.cli", "view", str(bundle), *args]
    if env is None:
        cmd = [XVFB_RUN, "-a", *cmd]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=240, env=env)


def _expected(bundle_dir: Path, cams: Cameras, index: int, mode: str = "neural", skybox: bool = True):
    from neuras_distill.playback.renderer import BundleRenderer

    with BundleRenderer(mode_bundle(load_bundle(bundle_dir), mode)) as r:
        return r.render(cams, index, skybox=skybox)


@needs_gl
@needs_xvfb
@pytest.mark.parametrize("kind, args, index, mode, skybox", [
    ("two-layer", (), 0, "neural", True),
    ("two-layer", ("--camera", "1"), 1, "neural", True),
    ("skybox", (), 0, "neural", True),
    ("skybox", ("--no-skybox",), 0, "neural", False),
    ("plain", ("--mode", "plain"), 0, "plain", True),
])
@pytest.mark.slow
def test_window_screenshot_is_the_renderers_frame(runs, tmp_path, kind, args, index, mode, skybox):
    bundle_dir, cams = runs[kind]
    shot = tmp_path / "w.png"
    proc = _view(bundle_dir, "--screenshot", str(shot), *args)
    assert proc.returncode == 0, proc.stderr
    got = np.asarray(Image.open(shot), np.float32) / 255.0
    want = _expected(bundle_dir, cams, index, mode, skybox)
    assert got.shape == want.shape == (cams.height, cams.width, 3)      # the start camera's own size
    assert psnr(got, want) >= 50.0
    assert got.std() > 0.02                                              # not a blank window


@needs_gl
@needs_xvfb
@pytest.mark.slow
def test_window_modes_differ_from_the_neural_shader(runs, tmp_path):
    bundle_dir, _ = runs["plain"]
    shots = {}
    for mode in VIEW_MODES:
        shots[mode] = tmp_path / f"{mode}.png"
        proc = _view(bundle_dir, "--screenshot", str(shots[mode]), "--mode", mode)
        assert proc.returncode == 0, proc.stderr
    images = {m: np.asarray(Image.open(p), np.float32) / 255.0 for m, p in shots.items()}
    for mode in ("plain", "uv", "index"):
        assert psnr(images[mode], images["neural"]) < 30.0, mode


KEYS_SCRIPT = """
import sys
import numpy as np
from neuras_distill.bake.bundle import load_bundle
from neuras_distill.playback.viewer import start_cameras
from neuras_distill.playback.window import WindowPlayer
bundle = load_bundle(sys.argv[1])
player = WindowPlayer(bundle, start_cameras(bundle, sys.argv[1])[0], 0)
g = player.glfw
start = player.control.c2w.copy()
def press(key):
    player._on_key(None, key, 0, g.PRESS, 0)
    player.draw_frame()
    return [player.mode, player.skybox, player.index]
out = {"2": press(g.KEY_2), "k": press(g.KEY_K), "4": press(g.KEY_4), "n": press(g.KEY_N)}
player.control.orbit(50.0, 10.0)
moved = not np.array_equal(player.control.c2w, player.control.start)
press(g.KEY_R)
out["reset"] = [moved, bool(np.array_equal(player.control.c2w, player.control.start))]
out["title"] = player._title(30.0)
player.close()
print(out)
"""


@needs_gl
@needs_xvfb
@pytest.mark.slow
def test_window_keys_switch_modes_skybox_and_cameras(runs):
    proc = subprocess.run([XVFB_RUN, "-a", sys.executable, "-c", KEYS_SCRIPT, str(runs["plain"][0])],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    out = ast.literal_eval(proc.stdout.strip().splitlines()[-1])
    assert out["2"] == ["plain", True, 0]
    assert out["k"] == ["plain", False, 0]
    assert out["4"] == ["index", False, 0]
    assert out["n"] == ["index", False, 1]
    assert out["reset"] == [True, True]
    assert "| index |" in out["title"] and "ms/frame" in out["title"] and "sky off" in out["title"]


@pytest.mark.slow
def test_view_without_a_display_says_how_to_get_one(runs, tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    shot = tmp_path / "w.png"
    proc = _view(runs["two-layer"][0], "--screenshot", str(shot), env=env)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--orbit" in lines[0] and "xvfb-run" in lines[0], proc.stderr
    assert not shot.exists() and not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, message", [
    (("--mode", "normals"), "unknown view mode"),
    (("--camera", "7"), "out of range"),
    (("--screenshot", "w.jpg"), "give a .png path"),
])
@pytest.mark.slow
def test_view_bad_options_exit_2(runs, tmp_path, args, message):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    proc = _view(runs["two-layer"][0], *args, env=env)       # refused before any window opens
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr


@pytest.mark.slow
def test_view_refuses_a_foreign_cameras_json(runs, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(runs["two-layer"][0], run / "bundle")
    (run / "cameras.json").write_text(json.dumps({"frames": []}))
    proc = _view(run / "bundle", env=dict(os.environ, DISPLAY=":4242"))
    assert proc.returncode == 2 and "is not a cameras.json of a run" in proc.stderr, proc.stderr


def test_camera_at_builds_one_world_camera():
    pose = _start_pose()
    cams = camera_at(pose, (100.0, 100.0, 64.0, 48.0), 128, 96)
    assert len(cams) == 1 and (cams.width, cams.height) == (128, 96)
    np.testing.assert_allclose(cams.c2w[0].double().numpy(), pose, atol=1e-6)


@needs_gl
def test_orbit_frames_of_a_bundle_away_from_the_origin_show_it(runs, tmp_path):
    from neuras_distill.playback.viewer import render_orbit_frames

    bundle = load_bundle(runs["two-layer"][0])
    assert np.abs(bundle.origin).max() > 100                          # the test bundles sit at x = 1000
    paths = render_orbit_frames(bundle, tmp_path / "orbit", frames=2, width=64, height=48)
    img = np.asarray(Image.open(paths[0]), np.float32) / 255.0
    covered = np.any(np.abs(img - bundle.background_color) > 2 / 255, axis=-1)
    assert 0.05 < covered.mean() < 0.95                               # the whole mesh in view, framed
