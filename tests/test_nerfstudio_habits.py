"""nerfstudio's habits in ``from-nerfstudio``: the dataset config.yml names gives the cameras, ``--load-config``.

The fixture ``tests/data/nerfstudio/orbit360`` (nerfstudio's own trainer made it) names its dataset as it was on
the machine that trained it (``/tmp/ns13/data``); its ``transforms.json`` lies beside ``config.yml``. A copy laid
out as ``ns-train`` leaves a project (``outputs/<exp>/nerfacto/<timestamp>/`` beside ``data/<scene>/``) with a
relative data path finds the dataset from the project folder.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from neuras_distill.cli_parser import build_parser
from neuras_distill.run_inputs import run_inputs

RUN = Path(__file__).parent / "data" / "nerfstudio" / "orbit360"
FRAMES = len(json.loads((RUN / "transforms.json").read_text())["frames"])


def _inputs(*argv: str):
    args = build_parser().parse_args(["from-nerfstudio", *argv])
    field, cameras, _ = run_inputs(args)
    return args, field, cameras


def _project(tmp_path: Path, data: str, with_dataset: bool = True) -> Path:
    """A copy of the run as ns-train leaves it in a project folder; config.yml naming ``data``; returns the run."""
    run = tmp_path / "project" / "outputs" / "orbit360" / "nerfacto" / "2026-11-30_120000"
    shutil.copytree(RUN, run, ignore=shutil.ignore_patterns("transforms.json", "reference_renders.npz"))
    text = (run / "config.yml").read_text()
    named = "!!python/object/apply:pathlib.PosixPath\n- /\n- tmp\n- ns13\n- data\n"
    assert text.count(named) == 1
    parts = "".join(f"- {p}\n" for p in Path(data).parts)
    (run / "config.yml").write_text(text.replace(named, f"!!python/object/apply:pathlib.PosixPath\n{parts}"))
    if with_dataset:
        (tmp_path / "project" / "data" / "orbit360").mkdir(parents=True)
        shutil.copy(RUN / "transforms.json", tmp_path / "project" / "data" / "orbit360" / "transforms.json")
    return run


def test_without_cameras_the_run_uses_the_transforms_beside_its_config():
    args, field, cameras = _inputs(str(RUN / "config.yml"))
    assert cameras is not None and len(cameras) == FRAMES
    assert args.cameras == str(RUN / "transforms.json")
    assert "beside config.yml (the dataset config.yml names, /tmp/ns13/data, is not here)" in args.cameras_said
    assert args.cameras_said in field.notes


def test_a_relative_dataset_is_found_from_the_project_folder(tmp_path, monkeypatch):
    run = _project(tmp_path, "data/orbit360")
    monkeypatch.chdir(tmp_path)                          # not the project folder: found from the run's ancestors
    args, _, cameras = _inputs("--load-config", str(run / "config.yml"))
    assert len(cameras) == FRAMES
    assert Path(args.cameras) == tmp_path / "project" / "data" / "orbit360" / "transforms.json"
    assert "(the dataset config.yml names)" in args.cameras_said


def test_no_dataset_is_one_line_naming_cameras(tmp_path):
    run = _project(tmp_path, "data/elsewhere", with_dataset=False)
    args, _, cameras = _inputs(str(run))
    assert cameras is None
    assert args.cameras_said == ("cameras: the dataset config.yml names (data/elsewhere) has no transforms.json "
                                 "here: an orbit around the foreground box instead; give the dataset's "
                                 "transforms.json with --cameras")


@pytest.mark.slow
def test_load_config_and_run_must_agree(tmp_path):
    other = _project(tmp_path, "data/orbit360")
    for argv, fragment in (([], "needs the run"),
                           ([str(RUN / "config.yml"), "--load-config", str(other / "config.yml")],
                            "name different runs")):
        out = subprocess.run([sys.executable, "-m", "neuras_distill.cli", "from-nerfstudio", *argv, "--out",
                              str(tmp_path / "run"), "--quiet"], capture_output=True, text=True, timeout=120)
        lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        assert out.returncode == 2 and len(lines) == 1 and fragment in lines[0], out.stderr
        assert not (tmp_path / "run").exists()
