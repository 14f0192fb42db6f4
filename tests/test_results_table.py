"""benchmarks/results_table.py: the results table from run folders' report.json, on a real small run (conftest's
``small_run``) and on hand-made reports; docs/results.md is its output on benchmarks/recorded/."""

from __future__ import annotations

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benchmarks" / "results_table.py"


def _module():
    spec = importlib.util.spec_from_file_location("results_table", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_row_from_a_handmade_report(tmp_path):
    rt = _module()
    report = {"source": {"command": ["neuras-distill", "from-ngp", "ball.ingp", "--out", "runs/ball", "--quiet"]},
              "device": {"field": "CPU: Some CPU (2 threads), torch 2.x",
                         "bundle": "OpenGL: llvmpipe (LLVM 15.0.7, 256 bits) (4.5 (Core Profile) Mesa 23.2)"},
              "resolution": [384, 216], "psnr": 39.7612, "flip": 0.01771, "psnr_interior": 37.981,
              "psnr_silhouette": 26.1, "psnr_smooth": 41.234, "speedup": 122.4, "distill_seconds": 348.0,
              "commit": "abc123def456", "created": "2026-01-02T03:04:05Z"}
    (tmp_path / "report.json").write_text(json.dumps(report))
    cells = _cells(rt.row(rt.load_report(tmp_path)))
    assert cells == ["`from-ngp ball.ingp`", "CPU, 2 threads / llvmpipe", "384x216", "39.76", "0.0177", "37.98",
                     "26.10", "41.23", "122x", "5.8 min", "abc123def456", "2026-01-02"]
    gpu = dict(report, device={"field": "GPU: NVIDIA H100 80GB HBM3 (cuda:0), torch 2.x, CUDA 12.x",
                               "bundle": "OpenGL: NVIDIA H100 80GB HBM3/PCIe/SSE2 (4.6.0 NVIDIA 550)"},
               psnr_silhouette=None, psnr_smooth=None, speedup=None, distill_seconds=54.7)
    del gpu["psnr_interior"]
    cells = _cells(rt.row(gpu))
    assert cells[1] == "NVIDIA H100 80GB HBM3 / NVIDIA H100 80GB HBM3/PCIe/SSE2"
    assert cells[5:10] == ["-", "-", "-", "-", "55 s"]


def test_refuses_what_is_not_a_report(tmp_path):
    rt = _module()
    with pytest.raises(SystemExit, match="no report.json"):
        rt.load_report(tmp_path)
    (tmp_path / "report.json").write_text(json.dumps({"speedup": 3}))
    with pytest.raises(SystemExit, match="not a run report"):
        rt.load_report(tmp_path)


@pytest.mark.gl
def test_table_of_a_real_run(small_run, tmp_path):
    """The script on a run folder the pipeline wrote: every column filled from that run's report.json."""
    result, out = small_run
    rep = json.loads((out / "report.json").read_text())
    page = tmp_path / "results.md"
    done = subprocess.run([sys.executable, str(SCRIPT), str(out), "--out", str(page)], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    rows = [ln for ln in page.read_text().splitlines() if ln.startswith("| `")]
    assert len(rows) == 1
    cells = _cells(rows[0])
    assert cells[0] == "`python API`" or cells[0].startswith("`neuras_distill") or "SphereSDF" in cells[0]
    assert cells[2] == "128x128"
    assert float(cells[3]) == pytest.approx(rep["psnr"], abs=0.005)
    assert float(cells[4]) == pytest.approx(rep["flip"], abs=5e-5)
    assert float(cells[5]) == pytest.approx(rep["psnr_interior"], abs=0.005)
    assert cells[8] == f"{rep['speedup']:.0f}x"
    assert re.fullmatch(r"\d+ s|\d+\.\d min", cells[9])
    assert cells[10] == (rep["commit"] or "-")
    assert re.fullmatch(r"\d{4}-\d\d-\d\d", cells[11]) and cells[11] == rep["created"][:10]


def test_results_page_is_generated_from_the_records():
    rt = _module()
    records = sorted((ROOT / "benchmarks" / "recorded").glob("*.json"))
    assert len(records) >= 10
    expected = rt.page([rt.load_report(p) for p in records])
    assert (ROOT / "docs" / "results.md").read_text() == expected, (
        "docs/results.md is out of date: python benchmarks/results_table.py benchmarks/recorded/*.json "
        "--out docs/results.md")
