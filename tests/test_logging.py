"""Messages go through ``logging.getLogger("neuras_distill")``; the package prints nothing outside the command
line; ``-v`` and ``--quiet`` change what a run shows; one progress display runs over the run."""

from __future__ import annotations

import ast
import logging
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: The command line's own modules: the only ones that print (results to stdout, errors to stderr).
CLI_MODULES = {"neuras_distill/cli.py", "neuras_distill/tiles/commands.py"}


def test_no_print_in_the_package_outside_the_command_line():
    found = []
    for path in [*(ROOT / "neuras_distill").rglob("*.py"), *(ROOT / "adapters").rglob("*.py")]:
        rel = path.relative_to(ROOT).as_posix()
        if rel in CLI_MODULES:
            continue
        for node in ast.walk(ast.parse(path.read_text("utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                found.append(f"{rel}:{node.lineno}")
            if isinstance(node, ast.Name) and node.id == "print" and isinstance(node.ctx, ast.Load):
                found.append(f"{rel}:{node.lineno} (print passed as a value)")
    assert found == []


def test_the_library_installs_no_handler_but_a_null_one():
    import subprocess
    import sys

    code = ("import logging, neuras_distill as nd; nd.distill; from neuras_distill.logs import LOGGER; "
            "print([type(h).__name__ for h in LOGGER.handlers], LOGGER.level, LOGGER.propagate)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "['NullHandler'] 0 True"


@pytest.mark.gl
@pytest.mark.parametrize("flag", [None, "-v", "--quiet"])
def test_a_run_speaks_at_the_level_its_flags_ask(tmp_path, capfd, flag):
    from neuras_distill.cli import main

    argv = ["from-synthetic", "sphere", "--preset", "fast", "--eval-width", "64", "--steps", "40",
            "--out", str(tmp_path / "run")] + ([flag] if flag else [])
    try:
        assert main(argv) == 0
    finally:
        from neuras_distill.logs import install_cli_handler

        install_cli_handler("normal")
    err = capfd.readouterr().err
    if flag == "--quiet":
        assert err.strip() == "", err[:500]
        return
    assert "[1/7] cameras:" in err and "[7/7] evaluate:" in err and "geometry: UV unwrap" in err
    assert ("DEBUG" in err or "INFO neuras_distill" in err) == (flag == "-v")


def test_the_eta_adds_the_current_stage_to_the_plans_figures(monkeypatch):
    from neuras_distill.pipeline.progress import RunProgress

    now = [100.0]
    monkeypatch.setattr(time, "perf_counter", lambda: now[0])
    stages = ("cameras", "teacher", "geometry", "gbuffer", "distill", "bake", "evaluate")
    p = RunProgress(False, stages)
    p.start("teacher")
    assert p.eta() == (None, True)                  # nothing measured or planned yet
    now[0] += 10.0
    p.count(1, 5, "views")                          # 10 s a view: 40 s left, and the teacher's 50 s expected
    assert p.expected["teacher"] == pytest.approx(50.0)
    p.expect("distill", 30.0)
    p.expect("evaluate", 20.0)
    left, unplanned = p.eta()
    assert left == pytest.approx(40.0 + 30.0 + 20.0) and unplanned
    p.start("evaluate")
    now[0] += 5.0
    assert p.eta() == (pytest.approx(15.0), False)   # the plan's 20 s, 5 s of it spent
