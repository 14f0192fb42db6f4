"""End to end on a small analytic scene: the whole pipeline, the run folder, the report's contract keys,
OpenGL-vs-torch parity, and failures that leave nothing behind. The run itself is conftest's ``small_run`` (shared
with test_report_html.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import neuras_distill as nd
from neuras_distill.errors import BadInputError

pytestmark = [pytest.mark.gl]

CONTRACT_KEYS = {"fps_before", "fps_after", "speedup", "resolution", "device", "psnr", "ssim", "lpips",
                 "distill_seconds", "stage_seconds", "mesh_faces", "texture_resolution", "bundle_bytes",
                 "left_out", "error_vs_runtime"}


def test_report_has_the_contract(small_run):
    result, out = small_run
    rep = json.loads((out / "report.json").read_text())
    assert CONTRACT_KEYS <= set(rep)
    assert rep["resolution"] == [128, 128]
    assert rep["speedup"] == pytest.approx(rep["fps_after"] / rep["fps_before"])
    assert rep["fps_before"] > 0 and rep["fps_after"] > 0
    assert rep["mesh_faces"] > 100 and rep["bundle_bytes"] > 0
    assert {p["kind"] for p in rep["error_vs_runtime"]} == {"field", "bundle"}
    assert all(np.isfinite(p["psnr"]) and p["seconds_per_frame"] > 0 for p in rep["error_vs_runtime"])
    assert sum(rep["stage_seconds"].values()) <= rep["distill_seconds"] + 1e-6
    assert np.allclose(rep["scene_aabb"], result.report["scene_aabb"]) and np.asarray(rep["scene_aabb"]).shape == (2, 3)
    assert np.all(np.asarray(rep["scene_aabb"])[1] > np.asarray(rep["scene_aabb"])[0])
    assert rep["peak_rss_mb"] > 100 and rep["peak_gpu_mb"] is None and rep["processes"] == 1
    peaks = list(rep["stage_peak_rss_mb"].values())        # per stage, in run order: never falling
    assert list(rep["stage_peak_rss_mb"]) == list(rep["stage_seconds"])
    assert all(a <= b for a, b in zip(peaks, peaks[1:])) and 0 < peaks[-1] <= rep["peak_rss_mb"] + 1


def test_the_bundle_carries_its_plain_texture_and_exports_to_gltf(small_run, tmp_path):
    from neuras_distill.export.gltf import export_gltf

    result, out = small_run
    bundle = nd.load_bundle(out / "bundle")
    res = result.report["texture_resolution"]
    side = res if isinstance(res, int) else res[0]
    assert bundle.plain_rgb.shape == (side, side, 3) and bundle.plain_rgb.std() > 1.0
    assert result.report["plain_texture"]["texture"] == [side, side]
    glb = export_gltf(out / "bundle", tmp_path / "run.glb")
    assert np.array_equal(nd.load_bundle(glb).plain_rgb, bundle.plain_rgb)


def test_quality_and_parity(small_run):
    result, _ = small_run
    rep = result.report
    # A smooth sphere: even the fast preset must match the field closely.
    assert rep["psnr"] > 28.0, rep["psnr_per_view"]
    assert rep["ssim"] > 0.9
    assert rep["parity_psnr"] >= 40.0


def test_fidelity_keys(small_run):
    _, out = small_run
    rep = json.loads((out / "report.json").read_text())
    n = rep["views"]["test"]
    assert n >= 1
    assert rep["views"]["cameras"] == "given"                      # small_run passes its cameras
    for key in ("flip", "psnr_interior", "psnr_silhouette", "psnr_smooth", "smooth_fraction", "hole_fraction"):
        assert np.isfinite(rep[key]), key
        assert len(rep[f"{key}_per_view"]) == n and all(np.isfinite(v) for v in rep[f"{key}_per_view"]), key
    assert 0.0 < rep["flip"] < 0.2                       # a close match, but never a perfect 0
    assert 20.0 < rep["psnr_silhouette"] < rep["psnr_interior"] <= 100.0
    assert 0.0 <= rep["hole_fraction"] < 0.01            # the sphere's mesh covers what the field shows
    assert 0.3 < rep["smooth_fraction"] < 1.0 and rep["psnr_smooth"] > rep["psnr_silhouette"]
    assert rep["silhouette_band_px"] == 2                # 128x128: max(2, round(0.004 * 181))
    assert len(rep["crops"]) == n and all(set(c) == {"a", "b"} for c in rep["crops"])
    assert rep["crops"][0]["a"]["box"] == [0, 0, 128, 128]   # smaller than 256: the whole view
    md = (out / "report.md").read_text()
    assert "Fidelity by region" in md and "FLIP" in md and "crop_00_a.png" in md and "crop_00_b.png" in md
    from PIL import Image

    assert Image.open(out / "views" / "view_00.png").size == (4 * 128 + 3 * 4, 128)
    assert Image.open(out / "views" / "crop_00_a.png").size == (3 * 128 + 2 * 4, 128)
    assert (out / "views" / "crop_00_b.png").is_file()


def test_left_out_says_why(small_run):
    result, _ = small_run
    parts = {item["component"]: item["reason"] for item in result.report["left_out"]}
    assert "skyboxes" in parts and "constant colour" in parts["skyboxes"]
    assert "unseen faces" in parts  # the orbit never sees the sphere's poles from below


def test_run_folder_contents(small_run):
    _, out = small_run
    for name in ("report.json", "report.md", "error_vs_runtime.png", "cameras.json", "bundle/manifest.json",
                 "bundle/shader.frag", "bundle/mesh.npz", "views/view_00.png"):
        assert (out / name).is_file(), name
    assert not list(out.parent.glob(".run.tmp-*"))
    bundle = nd.load_bundle(out / "bundle")
    assert bundle.mesh.num_faces == json.loads((out / "report.json").read_text())["mesh_faces"]


def test_stability_check_runs_first_and_is_reported(small_run):
    result, out = small_run
    stab = json.loads((out / "report.json").read_text())["stability"]
    assert stab["verdict"] == "fine" and stab["applied"] == {}
    assert {it["name"] for it in stab["items"]} >= {"finite.geometry", "surface.present", "sdf.stiffness"}


def test_stiff_field_raises_the_teacher_steps_before_rendering():
    from neuras_distill.pipeline.run import _check_stability
    from neuras_distill.stability.extreme import make_extreme

    field = make_extreme("thin-shell")                # sigma 1e6 in a 0.002 shell
    cfg = nd.load_config("fast", overrides={
        "teacher": {"num_steps": nd.DistillConfig().teacher.num_steps},  # at its default: the check may raise it
        "geometry": {"grid_resolution": 48}})                           # chosen: kept, recommendation reported
    before = cfg.teacher.num_steps
    caller = cfg
    stab, cfg = _check_stability(field, field.default_cameras(4, 32, 32) if hasattr(field, "default_cameras") else
                                 nd.Cameras.orbit([0, 0, 0], 3.0, 4, width=32, height=32), caller, lambda m: None)
    # the caller's configuration is not changed: a second run with it starts from the same settings
    assert caller.teacher.num_steps == before and caller.geometry.surface == "auto" and cfg is not caller
    again, cfg_again = _check_stability(field, field.default_cameras(4, 32, 32), caller, lambda m: None)
    assert again["applied"] == stab["applied"] and cfg_again == cfg
    assert stab["verdict"] == "adapted"
    assert stab["applied"]["teacher.num_steps"] == [before, cfg.teacher.num_steps]
    assert cfg.teacher.num_steps >= 1024 > before
    # thinner than a voxel even at the largest grid: meshed from the teacher's surface depths, so no
    # grid is recommended and the chosen one is kept
    assert stab["applied"]["geometry.surface"] == ["auto", "depths"] and cfg.geometry.surface == "depths"
    assert cfg.geometry.grid_resolution == 48 and "geometry.grid_resolution" not in stab["not_applied"]


def test_field_without_surface_leaves_nothing(tmp_path):
    class Empty:
        kind = "sdf"
        aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
        background_color = torch.ones(3)

        def geometry(self, x):
            return torch.full((x.shape[0],), 5.0)

        def radiance(self, x, d):
            return torch.full((x.shape[0], 3), 0.5)

    cams = nd.Cameras.orbit([0, 0, 0], 3.0, 6, width=32, height=32)
    with pytest.raises(BadInputError, match="cannot be distilled: surface.present: the SDF has no zero crossing"):
        nd.distill(Empty(), cams, nd.load_config("fast"), out=tmp_path / "run", progress=False, log=lambda m: None)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_soft_fringe_gets_a_shell_and_the_facing_input(two_torch_threads):
    """The gradient ball's fringe is many pixels wide: the mesh moves out until it covers the field's partly
    opaque pixels, the shader gets |n . d| (and the shell's shader the view direction; the core's drops it, the
    ball being matte), the bundle plays what torch computes, and against the single mesh at the surface level
    (same tiny settings; both play with the soft-silhouette pass, which recovers part of the fringe on its
    own) the interior gains most, the core sitting where the colour comes from (docs/decisions.md "Where the colour comes from")."""
    field = nd.make_scene("gradient-ball")
    cams = field.default_cameras(24, 256, 144, held_out_every=6)     # the fast preset holds out every 6th
    base = {"train": {"steps": 800}, "eval": {"width": 256, "fps_frames": 3}, "teacher": {"train_width": 256},
            "texture": {"resolution": 192, "num_codes": 256}}
    runs = {}
    for mode in ("on", "off"):
        cfg = nd.load_config("fast", overrides={**base, "geometry": {"grid_resolution": 96, "enclose_fringe": mode}})
        runs[mode] = nd.distill(field, cams, cfg, progress=False, log=lambda m: None)
    on, off = runs["on"].report, runs["off"].report
    stats = on["mesh_stats"]
    assert stats["mc_fringe_missed_at_surface"] > 0.02 >= stats["mc_fringe_missed"]
    assert stats["mc_shell_from"] == "offsets of the core" and stats["mc_fringe_offset_voxels"] >= 1
    # two layers: the core at the colour level, the shell only draws outside the core's silhouette, so the
    # interior is not learnt through the fringe (a single shell loses interior PSNR to patches)
    assert runs["on"].bundle.mesh.core_faces is not None and stats["shell_faces"] > 0
    assert stats["mc_colour_level_used"] and stats["mc_colour_level"] > 2.0 * field.surface_level
    assert on["psnr_interior"] > off["psnr_interior"] + 3.0, (on["psnr_interior"], off["psnr_interior"])
    assert on["view_dependence"]["core"] is False
    assert runs["on"].bundle.manifest["use_facing"] and runs["on"].bundle.manifest["use_viewdir"]
    assert "facing" in runs["on"].bundle.fragment_shader and "v_normal" in runs["on"].bundle.fragment_shader
    assert not runs["off"].bundle.manifest["use_facing"]
    assert on["parity_psnr"] >= 40.0
    print(f"silhouette band {off['psnr_silhouette']:.2f} -> {on['psnr_silhouette']:.2f} dB, "
          f"interior {off['psnr_interior']:.2f} -> {on['psnr_interior']:.2f} dB, "
          f"overall {off['psnr']:.2f} -> {on['psnr']:.2f} dB")
    assert on["psnr_silhouette"] > off["psnr_silhouette"] + 0.3, (on["psnr_silhouette"], off["psnr_silhouette"])
    assert on["psnr"] > off["psnr"] + 1.0, (on["psnr"], off["psnr"])


def test_generated_cameras_are_named_as_such():
    import neuras_distill as nd
    from neuras_distill.pipeline.run import pick_cameras
    from neuras_distill.scenes.analytic import SphereSDF

    cams, origin = pick_cameras(SphereSDF(), None, nd.load_config("fast"))
    assert len(cams) == nd.load_config("fast").cameras.num_views
    assert origin == ("generated by SphereSDF.default_cameras: An orbit (z up, elevations 15..50 degrees) "
                      "framing the aabb (see :func:`orbit_framing`).")
