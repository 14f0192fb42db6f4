"""Metrics (PSNR/SSIM), settings with presets, run folders that never leave half-written output."""

from __future__ import annotations

import numpy as np
import pytest

from neuras_distill import metrics
from neuras_distill.config import load_config, preset_names
from neuras_distill.errors import BadInputError
from neuras_distill.pipeline.rundir import MARKER, RunFolder


def test_psnr_values():
    a = np.zeros((8, 8, 3))
    b = np.full((8, 8, 3), 0.1)
    assert metrics.psnr(a, b) == pytest.approx(20.0)
    assert metrics.psnr(a, a) == metrics.MAX_PSNR
    mask = np.zeros((8, 8), bool)
    mask[:2] = True
    c = a.copy()
    c[2:] = 1.0
    assert metrics.psnr(c, a, mask) == metrics.MAX_PSNR


def test_ssim_values():
    rng = np.random.default_rng(0)
    img = rng.random((40, 40, 3))
    assert metrics.ssim(img, img) == pytest.approx(1.0)
    noisy = np.clip(img + rng.normal(0, 0.2, img.shape), 0, 1)
    assert 0.2 < metrics.ssim(noisy, img) < 0.9
    unrelated = rng.random((40, 40, 3))
    assert metrics.ssim(unrelated, img) < 0.1


def test_presets_only_override():
    base = load_config()
    fast = load_config("fast")
    assert base.train.steps == 0 and fast.train.steps == 200   # automatic by default; the preset fixes it
    assert fast.train.lr == base.train.lr  # not mentioned in the preset: the default stands
    assert set(preset_names()) >= {"object", "fast", "quality"}
    assert load_config("object") == base
    quality = load_config("quality")        # wider features, training planned from texels
    assert (quality.texture.feature_dim, quality.train.steps) == (12, 0) and base.texture.feature_dim == 8
    assert base.texture.hidden == quality.texture.hidden == 32


def test_bad_settings(tmp_path):
    with pytest.raises(BadInputError, match="face budget"):
        load_config(overrides={"geometry": {"face_budget": 0}})
    with pytest.raises(BadInputError, match="unknown setting"):
        load_config(overrides={"train": {"stepz": 3}})
    with pytest.raises(BadInputError, match="unknown preset"):
        load_config("nope")
    bad = tmp_path / "bad.toml"
    bad.write_text("[train\nsteps=")
    with pytest.raises(BadInputError, match="not valid TOML"):
        load_config(path=bad)


def test_run_folder_is_atomic(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(RuntimeError):
        with RunFolder(out) as tmp:
            (tmp / "half.txt").write_text("x")
            raise RuntimeError("boom")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
    with RunFolder(out) as tmp:
        (tmp / "a.txt").write_text("1")
    assert (out / "a.txt").read_text() == "1" and (out / MARKER).exists()
    with RunFolder(out) as tmp:  # ours: replaced
        (tmp / "b.txt").write_text("2")
    assert not (out / "a.txt").exists() and (out / "b.txt").exists()


def test_run_folder_refuses_foreign(tmp_path):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    with pytest.raises(BadInputError, match="not written by neuras-distill"):
        RunFolder(foreign)
    assert (foreign / "thesis.tex").read_text() == "precious"


def test_skybox_texture_and_eval_settings_are_validated():
    from neuras_distill.config import load_config
    from neuras_distill.errors import BadInputError

    cfg = load_config(overrides={"eval": {"width": 0}, "texture": {"resolution": 0}, "skybox": {"mode": "off"}})
    assert cfg.eval.width == 0 and cfg.texture.resolution == 0 and cfg.skybox.mode == "off"
    for bad, needle in (({"skybox": {"mode": "sometimes"}}, "skybox mode"),
                        ({"skybox": {"layers": 17}}, "layer count"),
                        ({"skybox": {"near": 100.0, "far": 10.0}}, "must nest"),
                        ({"texture": {"resolution": 8}}, "texture resolution"),
                        ({"eval": {"width": 8}}, "at least 16"),
                        ({"eval": {"max_upscale": -1.0}}, "max_upscale"),
                        ({"train": {"run_budget_s": -5.0}}, "time budget"),
                        ({"train": {"texture_lr_scale": 0.0}}, "texture_lr_scale"),
                        ({"train": {"lr": float("nan")}}, "train.lr"),
                        ({"train": {"patch": 0}}, "train.patch"),
                        ({"texture": {"quantize_above": 70000}}, "quantize_above"),
                        ({"texture": {"coarse_factor": 0}}, "coarse_factor")):
        with pytest.raises(BadInputError, match=needle):
            load_config(overrides=bad)
    from neuras_distill.pipeline.rules import capped_width

    assert capped_width(1920, 192) == 384 and capped_width(1920, 192, 0.0) == 1920 and capped_width(640, 192, 0) == 640
    assert capped_width(1920, 1920) == 1920 and capped_width(1920, 192, 4.0) == 768


def test_a_config_file_changes_a_scenes_own_preset_instead_of_replacing_it(tmp_path):
    from neuras_distill.cli_parser import build_parser
    from neuras_distill.run_inputs import run_inputs

    tweak = tmp_path / "codes.toml"
    tweak.write_text("[texture]\nnum_codes = 1024\n")
    parse = build_parser().parse_args
    _, _, plain = run_inputs(parse(["from-synthetic", "street"]))
    _, _, tweaked = run_inputs(parse(["from-synthetic", "street", "--config", str(tweak)]))
    assert plain.eval.width != load_config().eval.width             # the street preset is in force
    assert tweaked.texture.num_codes == 1024
    back = tweaked.updated({"texture": {"num_codes": plain.texture.num_codes}})
    assert back.to_dict() == plain.to_dict()                        # the file changed that one setting only


def test_the_configuration_is_frozen_and_each_section_checks_itself():
    import dataclasses

    from neuras_distill.config import DistillConfig, GeometryConfig, TextureConfig

    cfg = DistillConfig()
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.texture.num_codes = 3                                   # a run can never change its caller's settings
    for section in dataclasses.fields(cfg):
        part = getattr(cfg, section.name)
        assert part.validate() is part, section.name
    with pytest.raises(BadInputError, match="num_codes must be in 2..65535, got 1"):
        TextureConfig(num_codes=1).validate()
    with pytest.raises(BadInputError, match="grid resolution must be at least 16, got 8"):
        GeometryConfig(grid_resolution=8).validate()
    changed = cfg.updated({"geometry": {"grid_resolution": 48}})
    assert changed.geometry.grid_resolution == 48
    assert cfg.geometry.grid_resolution == DistillConfig().geometry.grid_resolution
    with pytest.raises(BadInputError, match="face budget must be at least 4"):
        cfg.updated({"geometry": {"face_budget": 2}})              # a changed copy is validated
