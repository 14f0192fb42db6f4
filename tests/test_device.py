"""``--device`` / ``nd.distill(device=)``: parsing, one-line refusals, fields moved to a device, GPU memory
running out, and the report's devices. CUDA itself is not on this machine: the device plumbing of the fields is
checked on torch's ``meta`` device (shapes only, no data), which refuses, as CUDA does, to mix its tensors with
host tensors."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch

from neuras_distill.config import TextureConfig, TrainConfig
from neuras_distill.device import OUT_OF_MEMORY, chunk_for_memory, field_device, move_field, resolve_device
from neuras_distill.device_field import DeviceField, on_device
from neuras_distill.errors import BadInputError
from neuras_distill.pipeline.report_json import device_info
from neuras_distill.playback.context import software_gl
from neuras_distill.scenes.synthetic import make_scene


def test_device_strings_resolve():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    expected = torch.device("cuda", 0) if torch.cuda.is_available() else torch.device("cpu")
    assert resolve_device("auto") == expected and resolve_device(None) == expected


@pytest.mark.parametrize("text", ["gpu", "cuda:x", "cpu:0", "", "cuda:-1", "mps", "auto:1"])
def test_a_string_that_is_not_a_device_is_refused(text):
    with pytest.raises(BadInputError, match="is not a device; use auto, cpu, cuda or cuda:N"):
        resolve_device(text)


def test_cuda_without_cuda_says_what_to_do(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for text in ("cuda", "cuda:0", "cuda:3"):
        with pytest.raises(BadInputError, match="use --device cpu") as err:
            resolve_device(text)
        assert ("CPU build" in str(err.value)) == (torch.version.cuda is None)
    assert resolve_device("auto") == torch.device("cpu")


def test_a_cuda_index_that_does_not_exist_is_refused(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert resolve_device("cuda") == torch.device("cuda", 0)
    assert resolve_device("cuda:1") == torch.device("cuda", 1)
    assert resolve_device("auto") == torch.device("cuda", 0)
    with pytest.raises(BadInputError,
                       match=r"'cuda:2' does not exist: this machine has 2 CUDA devices \(cuda:0 .. cuda:1\)"):
        resolve_device("cuda:2")


def _one_line_exit_2(args, tmp_path):
    out = tmp_path / "run"
    result = subprocess.run([sys.executable, "-m", "neuras_distill.cli", *args, "--out", str(out), "--quiet"],
                            capture_output=True, text=True, timeout=120)
    lines = [ln for ln in result.stderr.splitlines() if ln.strip()]
    assert result.returncode == 2 and len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert list(tmp_path.iterdir()) == []           # nothing written, not even a hidden partial folder
    return lines[0]


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
@pytest.mark.slow
def test_cli_cuda_on_a_machine_without_cuda_exits_2_with_one_line(tmp_path):
    line = _one_line_exit_2(["from-synthetic", "sphere", "--device", "cuda"], tmp_path)
    assert "device 'cuda'" in line and "--device cpu" in line


@pytest.mark.slow
def test_cli_a_device_that_is_not_one_exits_2(tmp_path):
    line = _one_line_exit_2(["demo", "--device", "gpu0"], tmp_path)
    assert "'gpu0' is not a device" in line


def test_chunks_follow_free_gpu_memory():
    assert chunk_for_memory(32768, 5120, "cpu") == 32768                        # the CPU keeps the given chunk
    assert chunk_for_memory(32768, 5120, "cuda", free=2 * 2**30) == 2 * 2**30 // 4 // 5120
    assert chunk_for_memory(32768, 5120, "cuda", free=2**20) == 1024            # at least 1024 rays
    assert chunk_for_memory(32768, 16, "cuda", free=80 * 2**30) == 8 * 32768    # at most 8x the default
    assert chunk_for_memory(2**14, 3200, "cuda", free=80 * 2**30, max_items=2**21) == 2**21  # the hash grid's cap


@pytest.mark.parametrize("name, kind", [("sphere", "sdf"), ("torus", "density"), ("gradient-ball", None)])
def test_fields_compute_on_the_device_they_are_moved_to(name, kind):
    """Every tensor a field computes with, stored or built per call, must be on the device: on ``meta`` a
    host tensor mixed in raises as it would on CUDA."""
    field = make_scene(name, kind=kind)
    aabb = field.aabb.clone()
    wrapped = on_device(field, torch.device("meta"))
    assert isinstance(wrapped, DeviceField) and field_device(wrapped).type == "meta"
    assert wrapped.aabb.device.type == "cpu" and torch.equal(wrapped.aabb, aabb)     # host metadata stays
    x, d = torch.rand(64, 3, device="meta"), torch.rand(64, 3, device="meta")
    geometry, colour = wrapped.geometry(x), wrapped.radiance(x, d)
    assert geometry.device.type == "meta" and tuple(geometry.reshape(-1).shape) == (64,)
    assert colour.device.type == "meta" and tuple(colour.shape) == (64, 3)
    assert wrapped.kind == field.kind


def test_the_cpu_leaves_the_field_alone():
    field = make_scene("gradient-ball")
    assert on_device(field, torch.device("cpu")) is field
    assert move_field(field, torch.device("cpu")) is field and field_device(field).type == "cpu"


def test_a_gpu_running_out_of_memory_ends_the_run_with_one_line(tmp_path, monkeypatch):
    import neuras_distill as nd
    from neuras_distill.pipeline import stages

    def out_of_memory(ctx, views):
        ctx.clock.start("teacher", "volume-rendering")
        raise OUT_OF_MEMORY("CUDA out of memory. Tried to allocate 2.00 GiB")

    monkeypatch.setattr(stages, "render_teacher", out_of_memory)
    with pytest.raises(BadInputError, match="ran out of memory during teacher.*--device cpu"):
        nd.distill(make_scene("sphere"), config={"cameras": {"num_views": 4, "width": 32, "height": 24},
                                                 "teacher": {"train_width": 32}},
                   out=tmp_path / "run", progress=False, log=lambda m: None)
    assert not (tmp_path / "run").exists()


def test_the_report_names_each_side_and_flags_software_gl_beside_a_gpu(monkeypatch):
    info = device_info({"renderer": "llvmpipe (LLVM 15.0.6, 256 bits)", "version": "4.5"}, "cpu")
    assert info["field"].startswith("CPU: ") and info["training"] == info["field"]
    assert info["bundle"].startswith("OpenGL: llvmpipe") and info["requested"] == "cpu"
    assert ("bundle_note" in info) == torch.cuda.is_available()
    assert software_gl("llvmpipe (LLVM 15)") and software_gl("Google SwiftShader")
    assert not software_gl("NVIDIA H100 80GB HBM3/PCIe/SSE2")


def test_the_training_speed_probe_follows_the_training_device():
    """The speed probe trains where the run trains (it measured the host's speed before)."""
    from neuras_distill.pipeline import rules
    speed = rules.probe_training_speed(TextureConfig(feature_dim=4, hidden=8, num_layers=2),
                                           TrainConfig(batch_patches=4, patch=8), steps=5, side=32, device="cpu")
    assert speed > 0
