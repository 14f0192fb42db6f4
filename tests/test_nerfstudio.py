"""nerfstudio runs (``from-nerfstudio``): config.yml read as data, checkpoints read weights-only, the nerfacto
field against nerfstudio's own evaluation, the data frame, and bad input.

The fixture ``tests/data/nerfstudio/bunny`` was made by ``scripts/make_nerfstudio_fixture.py`` with nerfstudio's
own ``NerfactoField`` class (implementation "torch"); ``reference_points.npz`` holds what nerfstudio's code
computed at 4096 points of its scene box.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from adapters.nerfstudio.adapter import NerfstudioAdapter
from adapters.nerfstudio.run import find_run, nerfacto_settings, read_config
from adapters.yaml_text import load_yaml
from neuras_distill.errors import BadInputError
from neuras_distill.registry import load_field

RUN = Path(__file__).parent / "data" / "nerfstudio" / "bunny"

#: the model section of a nerfacto config.yml of the nerfstudio 0.3 era (2023: no implementation, no
#: average_init_density, the VanillaDataManagerConfig), as PyYAML dumped it
OLD_CONFIG = """!!python/object:nerfstudio.engine.trainer.TrainerConfig
_target: !!python/name:nerfstudio.engine.trainer.Trainer ''
data: !!python/object/apply:pathlib.PosixPath
- data
- nerfstudio
- poster
method_name: nerfacto
output_dir: !!python/object/apply:pathlib.PosixPath
- outputs
pipeline: !!python/object:nerfstudio.pipelines.base_pipeline.VanillaPipelineConfig
  _target: !!python/name:nerfstudio.pipelines.base_pipeline.VanillaPipeline ''
  datamanager: !!python/object:nerfstudio.data.datamanagers.base_datamanager.VanillaDataManagerConfig
    _target: !!python/name:nerfstudio.data.datamanagers.base_datamanager.VanillaDataManager ''
    dataparser: !!python/object:nerfstudio.data.dataparsers.nerfstudio_dataparser.NerfstudioDataParserConfig
      _target: !!python/name:nerfstudio.data.dataparsers.nerfstudio_dataparser.Nerfstudio ''
      scene_scale: 1.0
    train_num_rays_per_batch: 4096
  model: !!python/object:nerfstudio.models.nerfacto.NerfactoModelConfig
    _target: !!python/name:nerfstudio.models.nerfacto.NerfactoModel ''
    background_color: last_sample
    collider_params:
      far_plane: 6.0
      near_plane: 2.0
    disable_scene_contraction: false
    far_plane: 1000.0
    hidden_dim: 64
    hidden_dim_color: 64
    log2_hashmap_size: 19
    max_res: 2048
    near_plane: 0.05
    num_levels: 16
    num_proposal_samples_per_ray: !!python/tuple
    - 256
    - 96
    use_average_appearance_embedding: true
relative_model_dir: !!python/object/apply:pathlib.PosixPath
- nerfstudio_models
"""


def test_config_yml_is_read_as_data_with_its_python_tags():
    config = read_config(RUN / "config.yml")
    assert config["method_name"] == "nerfacto" and config["_type"] == "nerfstudio.engine.trainer.TrainerConfig"
    assert config["data"] == "data/bunny" and config["relative_model_dir"] == "nerfstudio_models"
    s = nerfacto_settings(config)
    assert (s.implementation, s.log2_hashmap_size, s.num_levels, s.average_init_density, s.background_color) == (
        "torch", 13, 16, 0.01, "white")
    assert s.notes == []


def test_an_older_config_gets_the_defaults_of_its_version():
    s = nerfacto_settings(load_yaml(OLD_CONFIG, "old", python_tags=True))
    assert (s.implementation, s.average_init_density, s.log2_hashmap_size, s.background_color) == (
        "tcnn", 1.0, 19, "last_sample")
    assert s.appearance_embed_dim == 32 and s.use_average_appearance_embedding
    assert any("implementation" in n for n in s.notes) and any("average_init_density" in n for n in s.notes)


def test_a_constructor_tag_is_data_and_never_runs(tmp_path):
    marker = tmp_path / "ran"
    text = OLD_CONFIG + f"evil: !!python/object/apply:os.system\n- touch {marker}\n" \
                        f"evil2: !!python/object/new:subprocess.Popen\n  args: [[touch, {marker}]]\n"
    data = load_yaml(text, "evil", python_tags=True)
    assert data["evil"] == {"_apply": "os.system", "args": [f"touch {marker}"]}
    assert data["evil2"]["_type"] == "subprocess.Popen" and not marker.exists()


def test_unsupported_methods_are_named(tmp_path):
    text = OLD_CONFIG.replace("method_name: nerfacto", "method_name: splatfacto").replace(
        "nerfstudio.models.nerfacto.NerfactoModelConfig", "nerfstudio.models.splatfacto.SplatfactoModelConfig")
    with pytest.raises(BadInputError, match="method 'splatfacto'.*supported: nerfacto, nerfacto-big"):
        nerfacto_settings(load_yaml(text, "x", python_tags=True))


@pytest.mark.slow
def test_our_field_matches_nerfstudios_own_evaluation():
    """Must-show: max relative error <= 1e-3 on density where it is > 1e-2, <= 5e-3 on colour."""
    field = NerfstudioAdapter().load(RUN)
    ref = np.load(RUN / "reference_points.npz")
    x, d = torch.from_numpy(ref["positions"]), torch.from_numpy(ref["directions"])
    with torch.no_grad():
        sigma, rgb = field.network.density(x).numpy(), field.network.rgb(x, d).numpy()
    dense = ref["density"] > 1e-2
    assert dense.sum() > 100
    rel = np.abs(sigma[dense] - ref["density"][dense]) / ref["density"][dense]
    assert rel.max() <= 1e-3, rel.max()
    assert np.abs(rgb - ref["rgb"]).max() <= 5e-3


@pytest.mark.slow
def test_the_field_is_in_the_datasets_frame():
    field = NerfstudioAdapter().load(RUN)
    dp = json.loads((RUN / "dataparser_transforms.json").read_text())
    assert field.frame == "data" and field.scale == pytest.approx(dp["scale"])
    x = (torch.rand(256, 3) - 0.5) * 0.6 + field.aabb.mean(0)
    d = torch.nn.functional.normalize(torch.randn(256, 3), dim=-1)
    t = torch.tensor(dp["transform"], dtype=torch.float32)
    x_ns = dp["scale"] * (x @ t[:, :3].T + t[:, 3])
    with torch.no_grad():
        assert torch.allclose(field.geometry(x), dp["scale"] * field.network.density(x_ns), rtol=1e-4, atol=1e-6)
        assert torch.allclose(field.radiance(x, d), field.network.rgb(x_ns, d @ t[:, :3].T), atol=1e-5)
    # the box found from the density holds the bunny it was trained on (the scene's own box, same frame)
    from neuras_distill.scenes.synthetic import make_scene

    bunny = make_scene("bunny").aabb
    inner = (bunny[0] + 0.25 * (bunny[1] - bunny[0]), bunny[1] - 0.25 * (bunny[1] - bunny[0]))
    assert bool((field.aabb[0] <= inner[0]).all() and (field.aabb[1] >= inner[1]).all()), field.aabb
    assert not field.unbounded and torch.equal(field.background_color, torch.ones(3))


@pytest.mark.slow
def test_the_registry_finds_the_run_by_content():
    assert NerfstudioAdapter().sniff(RUN / "config.yml") and NerfstudioAdapter().sniff(RUN)
    assert not NerfstudioAdapter().sniff(RUN / "transforms.json")
    field = load_field(RUN / "config.yml")
    assert type(field).__name__ == "NerfstudioField"


def _copy_run(tmp_path) -> Path:
    run = tmp_path / "outputs" / "bunny" / "nerfacto" / "2026-11-25_000000"
    shutil.copytree(RUN, run)
    return run


def test_a_missing_checkpoint_and_mismatched_shapes_are_refused(tmp_path):
    run = _copy_run(tmp_path)
    cfg = (run / "config.yml").read_text()
    (run / "config.yml").write_text(cfg.replace("log2_hashmap_size: 13", "log2_hashmap_size: 14"))
    with pytest.raises(BadInputError, match="config and checkpoint are from different runs"):
        NerfstudioAdapter().load(run)
    for ckpt in (run / "nerfstudio_models").glob("*.ckpt"):
        ckpt.unlink()
    with pytest.raises(BadInputError, match=r"has no checkpoint \(nerfstudio_models/step-\*\.ckpt\)"):
        find_run(run)


class Smuggled:
    """A class a checkpoint's pickle names: loading it must be refused without constructing it."""

    def __reduce__(self):
        return (Path, ("smuggled",))


def test_checkpoints_with_foreign_globals_or_nan_weights_are_refused(tmp_path):
    run = _copy_run(tmp_path)
    ckpt_path = next((run / "nerfstudio_models").glob("*.ckpt"))
    ckpt = torch.load(ckpt_path, weights_only=False)     # our own fixture: trusted
    bad = dict(ckpt, extra=Smuggled())
    torch.save(bad, ckpt_path)
    with pytest.raises(BadInputError, match="found pathlib"):
        NerfstudioAdapter().load(run)
    ckpt["pipeline"]["_model.field.mlp_head.layers.0.weight"][0, 0] = float("nan")
    torch.save(ckpt, ckpt_path)
    with pytest.raises(BadInputError, match="mlp_head.layers.0.weight.*NaN"):
        NerfstudioAdapter().load(run)


def _tcnn_parts(s, n_app: int, gen: torch.Generator) -> dict:
    """Random weights of a small nerfacto in tcnn's shapes: grid table, base matrices, head matrices (padded)."""
    from adapters.nerfstudio.tcnn_layout import grid_config

    def mat(rows, cols):
        return torch.randn(rows, cols, generator=gen) / cols ** 0.5

    n_feat = s.num_levels * s.features_per_level
    pad16 = lambda n: (n + 15) // 16 * 16                                       # noqa: E731
    return {"table": (torch.rand(grid_config(s).n_params(), generator=gen) - 0.5) * 2.0,
            "base": [mat(s.hidden_dim, pad16(n_feat)), mat(pad16(1 + s.geo_feat_dim), s.hidden_dim)],
            "head": [mat(s.hidden_dim_color, pad16(16 + s.geo_feat_dim + n_app)),
                     mat(s.hidden_dim_color, s.hidden_dim_color), mat(16, s.hidden_dim_color)],
            "embedding": torch.randn(5, n_app, generator=gen)}


def _relu_chain(mats, h):
    for i, w in enumerate(mats):
        h = h @ w.T
        if i < len(mats) - 1:
            h = torch.relu(h)
    return h


def _pad(h, width, value):
    return torch.cat([h, torch.full((h.shape[0], width - h.shape[1]), value)], dim=1)


def test_the_tcnn_layout_of_each_nerfstudio_era_is_read():
    """tiny-cuda-nn's flat vectors (network first, then the grid; row-major padded matrices; inputs padded with
    0 after the grid and 1.0 after tcnn's Identity encoding) in the key names of three nerfstudio eras give the
    field computed from the parts directly (tcnn's grid, tcnn's SH of d, exp density, sigmoid colour)."""
    from adapters.nerfstudio.nerfacto import NerfactoNetwork, contract_inf
    from adapters.nerfstudio.run import NerfactoSettings
    from adapters.nerfstudio.tcnn_layout import grid_config
    from neuras_distill.components.tcnn import HashGridEncoding, sh_encode_deg4

    s = NerfactoSettings(num_levels=4, base_res=4, max_res=32, log2_hashmap_size=10, hidden_dim=16,
                         hidden_dim_color=16, appearance_embed_dim=4, average_init_density=0.5, implementation="tcnn")
    gen = torch.Generator().manual_seed(3)
    parts = _tcnn_parts(s, 4, gen)
    flat = lambda mats: torch.cat([m.reshape(-1) for m in mats])               # noqa: E731
    x = torch.rand(500, 3, generator=gen) * 3.0 - 1.5                          # inside and beyond the unit box
    d = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=-1)
    enc = HashGridEncoding(grid_config(s), parts["table"])((contract_inf(x) + 2.0) / 4.0)
    eras = {
        "nerfstudio >= 1.0.1": ({"mlp_base.model.params": torch.cat([flat(parts["base"]), parts["table"]]),
                                 "mlp_head.tcnn_encoding.params": flat(parts["head"])}, 0.0),
        "nerfstudio 0.3 .. 1.0": ({"mlp_base_grid.tcnn_encoding.params": parts["table"],
                                   "mlp_base_mlp.tcnn_encoding.params": flat(parts["base"]),
                                   "mlp_head.tcnn_encoding.params": flat(parts["head"])}, 1.0),
        "nerfstudio 0.1 .. 0.2": ({"mlp_base.params": torch.cat([flat(parts["base"]), parts["table"]]),
                                   "mlp_head.params": flat(parts["head"])}, 0.0),
    }
    app = parts["embedding"].mean(0)
    for era, (state, base_pad) in eras.items():
        state = dict(state, **{"embedding_appearance.embedding.weight": parts["embedding"]})
        net = NerfactoNetwork(state, s, source=era)
        assert net.layout == f"tcnn ({era})"
        out = _relu_chain(parts["base"], _pad(enc, 16, base_pad))
        inside = (((contract_inf(x) + 2.0) / 4.0 > 0) & ((contract_inf(x) + 2.0) / 4.0 < 1)).all(-1)
        want_density = 0.5 * torch.exp(out[:, 0]) * inside
        head_in = torch.cat([sh_encode_deg4(d), out[:, 1:16], app.expand(500, -1)], dim=1)
        want_rgb = torch.sigmoid(_relu_chain(parts["head"], _pad(head_in, 48, 1.0))[:, :3])
        with torch.no_grad():
            assert torch.allclose(net.density(x), want_density, rtol=1e-5, atol=1e-6), era
            assert torch.allclose(net.rgb(x, d), want_rgb, rtol=1e-5, atol=1e-6), era


def test_a_tcnn_checkpoint_that_does_not_match_its_config_is_refused():
    from adapters.nerfstudio.nerfacto import NerfactoNetwork
    from adapters.nerfstudio.run import NerfactoSettings

    s = NerfactoSettings(num_levels=4, base_res=4, max_res=32, log2_hashmap_size=10, hidden_dim=16,
                         hidden_dim_color=16, appearance_embed_dim=4)
    parts = _tcnn_parts(s, 4, torch.Generator().manual_seed(0))
    state = {"mlp_base.model.params": torch.cat([p.reshape(-1) for p in parts["base"]] + [parts["table"]]),
             "mlp_head.tcnn_encoding.params": torch.cat([p.reshape(-1) for p in parts["head"]]),
             "embedding_appearance.embedding.weight": parts["embedding"]}
    bigger = NerfactoSettings(**{**s.__dict__, "log2_hashmap_size": 11})       # config from another run
    with pytest.raises(BadInputError, match=r"mlp_base.model.params has [\d,]+ parameters.*different runs"):
        NerfactoNetwork(state, bigger)
    state["mlp_head.tcnn_encoding.params"] = state["mlp_head.tcnn_encoding.params"][:-7]
    with pytest.raises(BadInputError, match=r"mlp_head.tcnn_encoding.params has .*colour MLP"):
        NerfactoNetwork(state, s)


@pytest.mark.slow
def test_a_run_configured_for_tcnn_but_trained_without_it_reads_as_torch(tmp_path):
    """nerfstudio falls back to its torch modules when tiny-cuda-nn is missing: the keys decide the layout."""
    run = _copy_run(tmp_path)
    (run / "config.yml").write_text((run / "config.yml").read_text().replace("implementation: torch",
                                                                            "implementation: tcnn"))
    field = NerfstudioAdapter().load(run)
    assert field.network.layout == "torch"
    ref = np.load(RUN / "reference_points.npz")
    with torch.no_grad():
        sigma = field.network.density(torch.from_numpy(ref["positions"])).numpy()
    dense = ref["density"] > 1e-2
    assert np.max(np.abs(sigma[dense] - ref["density"][dense]) / ref["density"][dense]) < 1e-3


@pytest.mark.slow
def test_cli_bad_runs_exit_2_with_one_line(tmp_path):
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "config.yml").write_text("a: 1\n")
    for target, fragment in ((tmp_path / "missing", "does not exist"),
                             (tmp_path / "notes", "not a nerfstudio config.yml")):
        out = subprocess.run([sys.executable, "-m", "neuras_distill.cli", "from-nerfstudio", str(target), "--out",
                              str(tmp_path / "run"), "--quiet"], capture_output=True, text=True, timeout=120)
        lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        assert out.returncode == 2 and len(lines) == 1 and fragment in lines[0], out.stderr
        assert not (tmp_path / "run").exists()


@pytest.mark.slow
def test_runs_the_teacher_cannot_place_exit_2_with_one_line(tmp_path):
    """No dataparser_transforms.json (no frame, scale or far plane), and a far plane float32 cannot resolve
    against the scene: one line each, exit 2, no run folder."""
    no_transforms = _copy_run(tmp_path / "a")
    (no_transforms / "dataparser_transforms.json").unlink()
    too_far = _copy_run(tmp_path / "b")
    cfg = (too_far / "config.yml").read_text()
    (too_far / "config.yml").write_text(cfg.replace("far_plane: 1000.0", "far_plane: 1.0e+12"))
    for target, fragment in ((no_transforms, "has no dataparser_transforms.json"),
                             (too_far, "float32 cannot resolve the near scene")):
        out = subprocess.run([sys.executable, "-m", "neuras_distill.cli", "from-nerfstudio", str(target), "--out",
                              str(tmp_path / "run"), "--quiet"], capture_output=True, text=True, timeout=300)
        lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        assert out.returncode == 2 and len(lines) == 1 and fragment in lines[0], out.stderr
        assert not (tmp_path / "run").exists()


@pytest.mark.gl
@pytest.mark.slow
def test_a_nerfacto_run_distills_end_to_end(tmp_path):
    """The fixture through every stage on ten of its dataset's cameras (small sizes; the full-size run is in the
    README): the bundle plays and scores against the field."""
    import neuras_distill as nd
    from neuras_distill.render.cameras import Cameras

    field = load_field(RUN / "config.yml")
    cams = Cameras.from_transforms(RUN / "transforms.json")[::4]
    # no extra views: their probe renders 8 views of this slow field to decide what the run leaves out anyway
    config = {"cameras": {"test_every": 6, "extra_views": "off"},
              "teacher": {"num_steps": 128, "train_width": 96, "occupancy_resolution": 64},
              "geometry": {"grid_resolution": 96, "face_budget": 6000}, "texture": {"resolution": 192, "num_codes": 256},
              "train": {"steps": 300}, "eval": {"width": 96, "fps_frames": 5, "runtime_steps": [32]}}
    result = nd.distill(field, cams, config=config, out=tmp_path / "run", progress=False, log=lambda m: None)
    rep = result.report
    assert rep["psnr"] > 20.0 and rep["speedup"] > 1.0, (rep["psnr"], rep["speedup"])
    assert rep["views"]["test"] == 2 and (tmp_path / "run" / "bundle" / "manifest.json").is_file()


@pytest.mark.slow
def test_ns_export_camera_files_are_moved_into_the_datasets_frame(tmp_path):
    """``ns-export cameras`` writes poses in nerfstudio's frame without intrinsics: with --image-size and --focal
    they become the dataset's cameras again."""
    from neuras_distill.cli_parser import build_parser
    from neuras_distill.run_inputs import run_inputs
    from neuras_distill.render.cameras import Cameras

    data = Cameras.from_transforms(RUN / "transforms.json")
    dp = json.loads((RUN / "dataparser_transforms.json").read_text())
    t, scale = np.asarray(dp["transform"]), float(dp["scale"])
    frames = []
    for c2w in data.c2w.double().numpy():
        pose = np.concatenate([t[:, :3] @ c2w[:3, :3], (scale * (t[:, :3] @ c2w[:3, 3] + t[:, 3]))[:, None]], 1)
        frames.append({"file_path": "images/x.png", "transform": pose.tolist()})
    exported = tmp_path / "transforms_train.json"
    exported.write_text(json.dumps(frames))
    focal = float(data.fx[0])
    args = build_parser().parse_args(["from-nerfstudio", str(RUN), "--cameras", str(exported), "--image-size",
                                      f"{data.width}x{data.height}", "--focal", str(focal)])
    _, cams, _ = run_inputs(args)
    assert len(cams) == len(data) and (cams.width, cams.height) == (data.width, data.height)
    assert torch.allclose(cams.c2w, data.c2w, atol=1e-4)
    assert torch.allclose(cams.fx, data.fx) and torch.allclose(cams.cx, data.cx)
    args = build_parser().parse_args(["from-nerfstudio", str(RUN), "--cameras", str(exported)])
    with pytest.raises(BadInputError, match="poses only; give the images' size and focal length"):
        run_inputs(args)
