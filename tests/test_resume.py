"""Resumable, reproducible runs end to end, through the command line in subprocesses: a run killed with
SIGKILL during distillation finishes when the same command runs again, reusing the teacher and the geometry
and continuing training from its checkpoint; two fresh runs with the same seed write byte-identical bundles."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time

import pytest


pytestmark = [pytest.mark.gl, pytest.mark.slow]

#: Training steps of the small run: long enough in training (a few seconds) to be killed in it.
STEPS = 600

#: Small enough for the suite.
CONFIG = f"""
[cameras]
num_views = 12
width = 96
height = 96
[train]
steps = {STEPS}
checkpoint_every_s = 0.2
[texture]
resolution = 128
num_codes = 128
[eval]
width = 128
fps_frames = 5
"""


def _command(out, config):
    return [sys.executable, "-m", "neuras_distill.cli", "from-synthetic", "sphere", "--preset", "fast",
            "--config", str(config), "--out", str(out)]


def _run(out, config):
    result = subprocess.run(_command(out, config), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    return result


def _bundle_digests(out):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted((out / "bundle").iterdir())}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("resume")
    config = root / "small.toml"
    config.write_text(CONFIG)
    _run(root / "whole", config)
    return root, config


def test_two_fresh_runs_with_the_same_seed_write_identical_bundles(runs):
    root, config = runs
    _run(root / "again", config)
    first, second = _bundle_digests(root / "whole"), _bundle_digests(root / "again")
    assert len(first) >= 6 and first == second


def test_a_run_killed_during_distillation_resumes_and_loses_nothing(runs):
    root, config = runs
    out = root / "killed"
    partial = root / ".killed.partial"
    proc = subprocess.Popen(_command(out, config), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 240
    try:
        while not list((partial / "work" / "checkpoints").glob("distill-*.pt")):
            assert proc.poll() is None, "the run ended before it wrote a training checkpoint"
            assert time.monotonic() < deadline, "no training checkpoint within 240 s"
            time.sleep(0.05)
        time.sleep(0.3)                                     # a little further into the training
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert not out.exists() and partial.is_dir()

    result = _run(out, config)
    report = json.loads((out / "report.json").read_text())
    resumed = report["resumed"]
    assert {"teacher", "plan", "geometry", "gbuffer"} <= set(resumed["stages"]) and "distill" not in resumed["stages"]
    assert resumed["from_step"] and 0 < resumed["from_step"] < STEPS
    assert "resumed: reused teacher" in result.stderr and f"from step {resumed['from_step']}" in result.stderr
    whole = json.loads((root / "whole" / "report.json").read_text())
    print(f"killed at step {resumed['from_step']} of {STEPS}; resumed PSNR {report['psnr']:.3f} dB, uninterrupted "
          f"{whole['psnr']:.3f} dB; work area {report['work_area']['bytes'] / 1e6:.1f} MB")
    assert abs(report["psnr"] - whole["psnr"]) <= 0.2, (report["psnr"], whole["psnr"])
    assert report["source"]["command"][:3] == ["neuras-distill", "from-synthetic", "sphere"]
    assert report["train_summary"]["steps"] == whole["train_summary"]["steps"] == STEPS
    leftovers = [p.name for p in root.iterdir() if p.name.startswith(".")]
    assert leftovers == [], leftovers
    assert (out / "work").is_dir() and report["work_area"]["bytes"] > 0
    assert not list((out / "work").glob("checkpoints/*")) and not list((out / "work").rglob(".*tmp*"))


def test_a_changed_setting_recomputes_exactly_the_stages_downstream_of_it(tmp_path, torch_threads):
    """In process, into one run folder: the same settings reuse everything; more steps re-train (the surface
    stays, the atlas side may follow the budget); another face budget re-meshes, the teachers stay."""
    import neuras_distill as nd
    from neuras_distill.scenes.analytic import SphereSDF

    field = SphereSDF(center=(0.0, 0.0, 0.0), radius=0.5)
    cams = field.default_cameras(10, 96, 96)

    def run(**overrides):
        cfg = nd.load_config("fast", overrides={"eval": {"width": 128, "fps_frames": 3},
                                                "texture": {"num_codes": 128, "resolution": 0, "max_resolution": 256},
                                                **overrides})
        return nd.distill(field, cams, cfg, out=tmp_path / "run", progress=False, log=lambda m: None).report

    with torch_threads(2):
        first = run(train={"steps": 200})
        same = run(train={"steps": 200})
        longer = run(train={"steps": 300})
        coarser = run(train={"steps": 300}, geometry={"face_budget": 3000})
    assert first["resumed"]["stages"] == []
    assert same["resumed"]["stages"] == ["teacher", "plan", "surface", "geometry", "gbuffer", "distill", "field_views"]
    assert same["psnr"] == first["psnr"]
    assert {"teacher", "surface", "field_views"} <= set(longer["resumed"]["stages"])
    assert "distill" not in longer["resumed"]["stages"] and longer["train_summary"]["steps"] == 300
    assert set(coarser["resumed"]["stages"]) == {"teacher", "plan", "field_views"}
    assert coarser["mesh_faces"] <= 3000 < first["mesh_faces"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    kept = {d.name: sorted(k.name for k in d.iterdir()) for d in (tmp_path / "run" / "work").iterdir()}
    assert all(len(v) == 1 for v in kept.values()), kept          # the work area holds this run's stages only
