"""Runs under torchrun (``pipeline/torchrun.py``): the launch read from the environment, and two torchrun "nodes"
on this machine (two ``torchrun --nnodes 2 --nproc-per-node 1`` processes started separately, one torch thread
each) distilling a small scene as ``--nproc 2`` does, refusing ranks that disagree, and ending with one line on
the surviving rank when a node dies, after which the same command resumes."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from neuras_distill.errors import BadInputError
from neuras_distill.pipeline.torchrun import Launch, launch_from_env

TORCHRUN = Path(sys.executable).with_name("torchrun")
SCENE = ["from-synthetic", "sphere", "--preset", "fast", "--steps", "120", "--eval-width", "96", "--device", "cpu"]


def test_the_launch_comes_from_torchrun_or_slurm_variables():
    base = {"MASTER_ADDR": "10.0.0.1", "MASTER_PORT": "29500"}
    assert launch_from_env({}) is None
    assert launch_from_env({"RANK": "0", "WORLD_SIZE": "1", **base}) is None          # one process: no launch
    assert launch_from_env({"RANK": "1", "WORLD_SIZE": "4", "LOCAL_RANK": "1", "LOCAL_WORLD_SIZE": "2",
                            "GROUP_RANK": "0", **base}) == Launch(1, 4, 1, 2, "torchrun", 0)
    assert launch_from_env({"SLURM_PROCID": "3", "SLURM_NTASKS": "4", "SLURM_LOCALID": "1",
                            "SLURM_NODEID": "1", **base}) == Launch(3, 4, 1, 1, "srun", 1)
    with pytest.raises(BadInputError, match="MASTER_PORT is not set; export it"):
        launch_from_env({"RANK": "0", "WORLD_SIZE": "2", "MASTER_ADDR": "h"})
    with pytest.raises(BadInputError, match="RANK='x' in the environment is not a whole number"):
        launch_from_env({"RANK": "x", "WORLD_SIZE": "2", **base})


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _node(args: list[str], rendezvous: list[str], log: Path) -> subprocess.Popen:
    """One torchrun "node" of two (a process group of its own, one torch thread), output in ``log``."""
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    return subprocess.Popen([str(TORCHRUN), "--nnodes", "2", "--nproc-per-node", "1", *rendezvous,
                             "-m", "neuras_distill.cli", *args], stdout=log.open("w"), stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)


def _static(port: int, node_rank: int) -> list[str]:
    return ["--node-rank", str(node_rank), "--master-addr", "127.0.0.1", "--master-port", str(port)]


def _wait(procs, timeout: float = 300.0) -> list[int]:
    deadline = time.monotonic() + timeout
    codes = []
    for p in procs:
        try:
            codes.append(p.wait(timeout=max(1.0, deadline - time.monotonic())))
        except subprocess.TimeoutExpired:
            for q in procs:
                _kill_node(q)
            raise
    return codes


def _kill_node(proc: subprocess.Popen) -> None:
    """SIGKILL a torchrun "node": its agent and every process under it (the agent starts its ranks in their own
    process groups, so killing its group alone would leave them running)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    tree, todo = [], [proc.pid]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo += children.get(pid, [])
    for pid in reversed(tree):
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, 9)


def _told(log: Path) -> str:
    """What a failed node's log says: its first lines (a rank's own abort comes first) and its last ones."""
    text = log.read_text()
    return text if len(text) <= 3000 else text[:1000] + "\n...\n" + text[-2000:]


def _our_lines(log: Path) -> list[str]:
    return [line for line in log.read_text().splitlines() if line.startswith("neuras-distill: error: ")]


pytestmark = [pytest.mark.skipif(not TORCHRUN.exists(), reason="torchrun is not installed beside python")]


@pytest.mark.gl
@pytest.mark.slow
def test_two_torchrun_nodes_make_the_bundle_nproc_2_makes(tmp_path):
    from neuras_distill.cli import main

    port = _port()
    rendezvous = ["--rdzv-backend", "c10d", "--rdzv-endpoint", f"127.0.0.1:{port}", "--rdzv-id", "same"]
    out = tmp_path / "torchrun"
    nodes = [_node([*SCENE, "--quiet", "--out", str(out)], rendezvous, tmp_path / f"node{i}.log") for i in (0, 1)]
    assert _wait(nodes) == [0, 0], [_told(tmp_path / f"node{i}.log") for i in (0, 1)]
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert main([*SCENE, "--quiet", "--nproc", "2", "--out", str(tmp_path / "nproc")]) == 0
    finally:
        torch.set_num_threads(threads)
    rep = json.loads((out / "report.json").read_text())
    assert rep["processes"] == 2 and rep["ranks"]["launcher"] == "torchrun" and rep["ranks"]["nodes"] == 2
    assert len(rep["ranks"]["teacher_seconds"]) == 2 and min(rep["ranks"]["training_seconds"]) > 0
    files = sorted(p.name for p in (out / "bundle").iterdir())
    assert files == sorted(p.name for p in (tmp_path / "nproc" / "bundle").iterdir())
    differ = [f for f in files if (out / "bundle" / f).read_bytes() != (tmp_path / "nproc" / "bundle" / f).read_bytes()]
    assert not differ, f"the torchrun bundle differs from --nproc 2's in {differ}"


@pytest.mark.slow
def test_ranks_that_disagree_end_with_one_line_naming_the_rank(tmp_path):
    port = _port()
    out = tmp_path / "run"
    nodes = [_node([*SCENE, "--quiet", "--out", str(out), *(["--steps", "150"] if i else [])], _static(port, i),
                   tmp_path / f"node{i}.log") for i in (0, 1)]
    _wait(nodes, timeout=180)
    for i in (0, 1):
        lines = _our_lines(tmp_path / f"node{i}.log")
        assert lines == ["neuras-distill: error: rank 1 (on " + socket.gethostname() + ") has another configuration "
                         "than rank 0; launch every rank with the same command, files and version"], lines
    assert not out.exists() and not list(tmp_path.glob(".run*"))


@pytest.mark.gl
@pytest.mark.slow
def test_a_node_that_dies_ends_the_run_with_one_line_and_the_relaunch_resumes(tmp_path):
    """Rank 1's node is killed while rank 0 trains (after the teacher and the mesh are stored); rank 0 ends with
    one line and keeps its finished stages; the same two commands, relaunched, reuse them and finish."""
    args = ["from-synthetic", "sphere", "--preset", "fast", "--steps", "1500", "--eval-width", "96",
            "--device", "cpu", "--out", str(tmp_path / "run")]
    port = _port()
    logs = [tmp_path / f"node{i}.log" for i in (0, 1)]
    nodes = [_node(args, _static(port, i), logs[i]) for i in (0, 1)]
    deadline = time.monotonic() + 180
    while "[5/7] distill" not in logs[0].read_text():
        assert time.monotonic() < deadline and nodes[0].poll() is None, logs[0].read_text()[-2000:]
        time.sleep(0.2)
    time.sleep(1.0)
    _kill_node(nodes[1])                                # the whole node: its torchrun agent and its rank
    _wait(nodes, timeout=120)
    lines = _our_lines(logs[0])
    assert len(lines) == 1 and lines[0].startswith("neuras-distill: error: rank 0: another rank (of 2 on 2 nodes) "
                                                   "failed or did not answer"), lines
    assert lines[0].endswith("relaunch the same command on every node: it resumes from the finished stages")
    port = _port()
    again = [_node(args, _static(port, i), tmp_path / f"again{i}.log") for i in (0, 1)]
    assert _wait(again) == [0, 0], (tmp_path / "again0.log").read_text()[-2000:]
    rep = json.loads((tmp_path / "run" / "report.json").read_text())
    assert {"teacher", "surface", "geometry"} <= set(rep["resumed"]["stages"]), rep["resumed"]
