"""Deferred playback (``playback/deferred.py``): a visibility buffer, then the bundle's shaders as compute passes.

On a rasterizing GPU it is the default player (an H100 drew the demo's 1080p frame in 0.30 ms of GPU time
against 1.01 ms forward); here, on llvmpipe, it is run explicitly and compared with the forward path pixel by
pixel on every kind of bundle the players know: one layer with the silhouette pass and a facing input, two
layers (one MLP each), skyboxes, atlas pages, the window's view modes. The only arithmetic that differs is the
barycentrics (a ray-plane intersection instead of the rasterizer's interpolation), so the pictures agree to
within one 8-bit level.
"""

from __future__ import annotations

import numpy as np
import pytest

from neuras_distill.bake.bundle import load_bundle
from neuras_distill.playback import deferred
from neuras_distill.playback.deferred import compute_shading_source, compute_supported
from neuras_distill.playback.renderer import BundleRenderer
from neuras_distill.playback.shaders import SILHOUETTE_FRAGMENT_SHADER
from neuras_distill.playback.view_modes import mode_bundle
from neuras_distill.render.cameras import Cameras
from test_web import ORIGIN, _run_folder

pytestmark = [pytest.mark.gl, pytest.mark.usefixtures("one_torch_thread")]


def _cameras(cams: Cameras | None) -> Cameras:
    return cams if cams is not None else Cameras.orbit(ORIGIN + [0.5, 0.5, 0.0], 2.2, 2, width=128, height=96,
                                                       elevation_deg=35.0, phase_deg=-60.0)


def _both(bundle, cams: Cameras, skybox: bool = True) -> tuple[list[np.ndarray], list[np.ndarray]]:
    with BundleRenderer(bundle, shading="forward") as fwd, BundleRenderer(bundle, shading="deferred") as dfr:
        assert (fwd.shading, dfr.shading) == ("forward", "deferred")
        return ([fwd.render(cams, i, skybox) for i in range(len(cams))],
                [dfr.render(cams, i, skybox) for i in range(len(cams))])


def assert_same_picture(want: list[np.ndarray], got: list[np.ndarray], what: str) -> None:
    for i, (a, b) in enumerate(zip(want, got)):
        levels = np.abs(a - b).max(-1) * 255.0
        assert levels.max() <= 2.01, f"{what}, view {i}: {levels.max():.1f} levels apart"
        assert (levels > 1.01).mean() < 1e-3, f"{what}, view {i}: {(levels > 1.01).mean():.2%} of pixels differ"


@pytest.mark.parametrize("kind", ["single", "two-layer", "skybox", "paged"])
def test_deferred_playback_draws_the_forward_picture(tmp_path, kind):
    path, cams = _run_folder(tmp_path, kind)
    bundle, cams = load_bundle(path), _cameras(cams)
    fwd, dfr = _both(bundle, cams)
    drawn = [float((np.abs(img - bundle.background_color).max(-1) > 0.02).mean()) for img in fwd]
    assert min(drawn) > 0.05, f"{kind}: the cameras see too little of the bundle ({drawn})"
    assert_same_picture(fwd, dfr, kind)
    if kind == "skybox":                   # without its sky pass the empty pixels take the clear colour
        fwd, dfr = _both(bundle, cams, skybox=False)
        assert_same_picture(fwd, dfr, "skybox left out")
        assert np.allclose(dfr[0][0, 0], np.round(np.asarray(bundle.background_color) * 255) / 255)


def test_the_window_view_modes_play_deferred(tmp_path):
    path, cams = _run_folder(tmp_path, "single")
    bundle, cams = load_bundle(path), _cameras(cams)
    for mode in ("uv", "index"):
        fwd, dfr = _both(mode_bundle(bundle, mode), cams)
        assert_same_picture(fwd, dfr, mode)


def test_a_view_without_the_mesh_is_background_only(tmp_path):
    path, _ = _run_folder(tmp_path, "single")
    bundle = load_bundle(path)
    away = Cameras.orbit(ORIGIN + [0.0, 0.0, 50.0], 1.0, 1, width=32, height=24, elevation_deg=80.0)
    with BundleRenderer(bundle, shading="deferred") as r:
        img = r.render(away, 0)
    assert np.allclose(img, np.round(np.asarray(bundle.background_color) * 255) / 255)


def test_timing_names_the_path_and_the_default_follows_the_gl(tmp_path):
    path, _ = _run_folder(tmp_path, "single")
    bundle, cams = load_bundle(path), _cameras(None)
    with BundleRenderer(bundle, shading="deferred") as r:
        t = r.time_frames(cams, warmup=1, frames=2)
        assert t["shading"] == "deferred" and t["median_ms"] > 0
    with BundleRenderer(bundle) as r:          # llvmpipe: compute shaders run slower there than fragments
        assert r.shading == "forward" and compute_supported(r.ctx)
    with pytest.raises(ValueError, match="shading must be"):
        BundleRenderer(bundle, shading="raytraced")


def test_the_compute_source_keeps_the_shader_and_refuses_foreign_ones():
    src = compute_shading_source(SILHOUETTE_FRAGMENT_SHADER, "pass")
    assert src.startswith("#version 430") and "gl_FragCoord.xy" not in src and "neurasFragCoord.xy" in src
    assert "texture(u_scene, p - h)" in src and src.count("#version") == 1
    foreign = SILHOUETTE_FRAGMENT_SHADER.replace("out vec4 f_color;", "in vec4 v_colour;\nout vec4 f_color;")
    with pytest.raises(ValueError, match="outside the playback interface"):
        compute_shading_source(foreign, "pass")
    with pytest.raises(ValueError, match="no 'void main"):
        compute_shading_source("#version 330\nout vec4 f_color;\n", "pass")
    with pytest.raises(ValueError, match="kind must be"):
        compute_shading_source(SILHOUETTE_FRAGMENT_SHADER, "volume")


def test_two_layer_sources_hold_one_function_per_layer(tmp_path):
    path, _ = _run_folder(tmp_path, "two-layer")
    src = compute_shading_source(load_bundle(path).fragment_shader, "mesh", two_layers=True)
    assert src.count("void neuras_shade_core()") == 1 and src.count("void neuras_shade_shell()") == 1
    assert "#undef MESH_LAYER" in src and "neuras_core_faces" in src
    assert deferred.GROUP[0] * deferred.GROUP[1] == 128


def test_a_shader_outside_the_compute_interface_plays_forward_unless_deferred_is_asked_for(tmp_path, monkeypatch):
    from neuras_distill.errors import BadInputError
    from neuras_distill.playback import renderer as renderer_module

    path, _ = _run_folder(tmp_path, "single")
    bundle = load_bundle(path)
    bundle.fragment_shader = bundle.fragment_shader.replace("void main() {",
                                                            "void main() {\n    if (v_uv.x < -1.0) discard;")
    with pytest.raises(BadInputError, match="compute passes"):
        BundleRenderer(bundle, shading="deferred")
    monkeypatch.setattr(renderer_module, "software_gl", lambda renderer: False)     # as on a rasterizing GPU
    with BundleRenderer(bundle) as r:
        assert r.shading == "forward" and r.deferred is None
        assert r.render(_cameras(None), 0).shape == (96, 128, 3)
