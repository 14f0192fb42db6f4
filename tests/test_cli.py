"""The command line: fast help, cheap import, exit code 2 with one line for bad input."""

from __future__ import annotations

import subprocess
import sys

import pytest

from neuras_distill.cli import main


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "neuras_distill.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=120)


def test_help_is_fast_and_imports_nothing_heavy():
    code = ("import sys, neuras_distill.cli as c\n"
            "try:\n    c.build_parser().parse_args(['--help'])\nexcept SystemExit: pass\n"
            "heavy = [m for m in ('torch', 'moderngl', 'igl', 'pymeshlab', 'xatlas', 'skimage') "
            "if m in sys.modules]\nprint('HEAVY', heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "HEAVY []" in out.stdout
    code = "import sys, neuras_distill as nd\nprint('HEAVY', [m for m in ('torch', 'moderngl') if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert "HEAVY []" in out.stdout


def _one_line_error(result, fragment):
    assert result.returncode == 2, result.stderr
    lines = [ln for ln in result.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert fragment in lines[0]


@pytest.mark.slow
def test_foreign_output_folder_is_refused(tmp_path):
    foreign = tmp_path / "notes"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    result = _run("demo", "--out", str(foreign), "--quiet")
    _one_line_error(result, "not written by neuras-distill")
    assert (foreign / "keep.txt").read_text() == "mine" and len(list(foreign.iterdir())) == 1


@pytest.mark.slow
def test_face_budget_zero(tmp_path):
    result = _run("demo", "--out", str(tmp_path / "r"), "--face-budget", "0", "--quiet")
    _one_line_error(result, "face budget")
    assert not (tmp_path / "r").exists()


@pytest.mark.slow
def test_a_time_budget_the_stages_before_training_spend_is_refused(tmp_path):
    result = _run("from-synthetic", "sphere", "--preset", "fast", "--time-budget", "1", "--out", str(tmp_path / "r"),
                  "--quiet")
    _one_line_error(result, "--time-budget 1: the stages before training took")
    assert "or more" in result.stderr and not (tmp_path / "r").exists()


@pytest.mark.slow
def test_unknown_scene(tmp_path):
    result = _run("from-synthetic", "teapot-xl", "--out", str(tmp_path / "r"), "--quiet")
    _one_line_error(result, "teapot-xl")
    assert list(tmp_path.iterdir()) == []


def test_view_missing_bundle(tmp_path, capsys):
    assert main(["view", str(tmp_path / "nothing"), "--orbit"]) == 2
    err = capsys.readouterr().err
    assert "nothing" in err and len(err.strip().splitlines()) == 1


# ---------------------------------------------------------------------------------------------- check
@pytest.mark.slow
def test_check_synthetic_bunny_prints_table():
    result = _run("check", "synthetic:bunny")
    assert result.returncode == 0, result.stderr
    assert "stability of synthetic:bunny (sdf field): FINE" in result.stdout
    for probe in ("sdf.stiffness", "sdf.eikonal", "sdf.sign", "scale.float32", "cameras.inside", "colour.range"):
        assert probe in result.stdout


@pytest.mark.slow
def test_check_stiff_shell_is_adapted(tmp_path):
    import json

    out = tmp_path / "stability.json"
    result = _run("check", "extreme:thin-shell", "--json", str(out))
    assert result.returncode == 0, result.stderr
    assert "ADAPTED" in result.stdout and "teacher.num_steps = 1024" in result.stdout
    data = json.loads(out.read_text())
    assert data["verdict"] == "adapted" and data["adaptations"]["teacher.num_steps"] == 1024
    stiff = next(it for it in data["items"] if it["name"] == "density.stiffness")
    assert stiff["values"]["sigma_delta_max"] > 1e3 and stiff["values"]["steps_needed"] == 1024


@pytest.mark.slow
def test_check_corrupt_checkpoint(tmp_path):
    bad = tmp_path / "scene.ingp"
    bad.write_bytes(bytes(range(256)) * 37)
    result = _run("check", str(bad))
    _one_line_error(result, "scene.ingp")


@pytest.mark.slow
def test_check_refused_field_exits_2_with_the_reason():
    result = _run("check", "extreme:flipped-sign")
    _one_line_error(result, "cannot be distilled: sdf.sign: the SDF is negative outside")
    assert "REFUSED" in result.stdout


def test_check_unknown_sources(tmp_path, capsys):
    assert main(["check", "extreme:teapot"]) == 2
    assert main(["check", str(tmp_path / "missing.ingp")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "teapot" in err[0] and "missing.ingp does not exist" in err[1]
