"""``tiles run CITY --ray``: every unfinished tile as a Ray task on a local 2-CPU Ray, byte-identical to the loop in
turn with fixed steps; a worker killed in the middle of a tile is retried with the same result; an address that
does not answer is one line."""

from __future__ import annotations

import filecmp
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from neuras_distill.cli import main

pytestmark = [pytest.mark.gl, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[1]


def _same_tiles(a: Path, b: Path, count: int) -> None:
    for k in range(count):
        left, right = a / "tiles" / str(k) / "tile", b / "tiles" / str(k) / "tile"
        names = sorted(p.name for p in left.iterdir())
        assert names == sorted(p.name for p in right.iterdir())
        _, mismatch, errors = filecmp.cmpfiles(left, right, names, shallow=False)
        assert mismatch == [] and errors == [], (k, mismatch, errors)


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """(a plan of the blocks scene in 2 tiles with fixed steps, the same plan run in turn with one torch thread)."""
    import torch

    root = tmp_path_factory.mktemp("ray")
    plan = root / "plan"
    assert main(["tiles", "plan", "synthetic:blocks", "--tile-size", "1.5", "--out", str(plan), "--preset", "fast",
                 "--steps", "600"]) == 0
    turn = root / "in-turn"
    shutil.copytree(plan, turn)
    old = torch.get_num_threads()
    torch.set_num_threads(1)                       # a Ray task of 1 CPU trains with 1 thread
    try:
        assert main(["tiles", "run", str(turn), "--quiet"]) == 0
    finally:
        torch.set_num_threads(old)
    return plan, turn


def test_ray_writes_the_tiles_of_the_loop_in_turn(planned, tmp_path):
    pytest.importorskip("ray")
    plan, turn = planned
    city = tmp_path / "city"
    shutil.copytree(plan, city)
    assert main(["tiles", "run", str(city), "--ray", "--quiet"]) == 0
    _same_tiles(turn, city, 2)
    assert main(["tiles", "run", str(city), "--ray", "--quiet"]) == 0        # finished: nothing to run


def test_a_worker_killed_mid_tile_is_retried_with_the_same_result(planned, tmp_path):
    pytest.importorskip("ray")
    plan, turn = planned
    city = tmp_path / "city"
    shutil.copytree(plan, city)
    killed = []

    def kill_one_worker():
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not killed:
            found = subprocess.run(["pgrep", "-f", "ray::_tile_task"], capture_output=True, text=True).stdout.split()
            if found:
                time.sleep(3.0)                         # into the tile's work
                found = subprocess.run(["pgrep", "-f", "ray::_tile_task"], capture_output=True,
                                       text=True).stdout.split()
                if found:
                    subprocess.run(["kill", "-9", found[0]])
                    killed.append(found[0])
            time.sleep(0.2)

    killer = threading.Thread(target=kill_one_worker, daemon=True)
    killer.start()
    done = subprocess.run([sys.executable, "-m", "neuras_distill.cli", "tiles", "run", str(city), "--ray"],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    killer.join(timeout=5)
    assert done.returncode == 0, done.stderr[-2000:]
    assert killed, "no Ray worker was found to kill"
    assert "after 2 attempts (its worker died; Ray ran it again)" in done.stderr, done.stderr[-2000:]
    assert not list((city / "tiles").glob(".ray-attempts-*"))
    _same_tiles(turn, city, 2)


@pytest.mark.parametrize("address, fragment", [("127.0.0.1:1", "nothing answers there"),
                                               ("no-port", "is not host:port")])
def test_an_address_that_does_not_answer_is_one_line(planned, tmp_path, capsys, address, fragment):
    pytest.importorskip("ray")
    plan, _ = planned
    city = tmp_path / "city"
    shutil.copytree(plan, city)
    capsys.readouterr()
    assert main(["tiles", "run", str(city), "--ray", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert not (city / "tiles").exists()
