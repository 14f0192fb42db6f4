"""Time per stage: one process against the same run split over torchrun ranks, on this machine.

    python benchmarks/torchrun_scaling.py OUT_DIR [--nnodes 2] [--nproc-per-node 1] [--threads N]
        [-- RUN ARGS ...]          # default: from-synthetic bunny --steps 2000 --device cpu

The one-process run gets ``--threads`` torch threads (default: the machine's CPUs); with ``--nnodes`` > 1 the
script starts that many ``torchrun --nnodes N --nproc-per-node M`` processes itself (static rendezvous on
127.0.0.1, each rank with threads / (N x M) threads), as separate machines would run them; with ``--nnodes 1`` one
``torchrun --standalone``. Fixed ``--steps`` make both bundles the same, so the figures compare the same work.
Prints one JSON line per run (``stage_seconds``, ``distill_seconds``, the report's ``ranks``) and one with the
ratio of each stage's time. On a machine with as many cores as ranks x threads this is the speedup; on 2 cores
with 2 ranks of 1 thread it shows the overhead of the split.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

DEFAULT_RUN = ["from-synthetic", "bunny", "--steps", "2000", "--device", "cpu"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _report(folder: Path) -> dict:
    rep = json.loads((folder / "report.json").read_text())
    return {"stage_seconds": rep["stage_seconds"], "distill_seconds": rep["distill_seconds"], "psnr": rep["psnr"],
            "ranks": rep.get("ranks")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    parser.add_argument("--nnodes", type=int, default=2)
    parser.add_argument("--nproc-per-node", type=int, default=1)
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("run", nargs="*", default=DEFAULT_RUN, help="the run command's arguments (after --)")
    args = parser.parse_args()
    ranks = args.nnodes * args.nproc_per_node
    cli = [sys.executable, "-m", "neuras_distill.cli", *args.run, "--quiet"]
    one = args.out / "one-process"
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads), MKL_NUM_THREADS=str(args.threads))
    subprocess.run([*cli, "--out", str(one)], check=True, env=env)
    first = _report(one)
    print(json.dumps({"run": "one process", "threads": args.threads, **first}), flush=True)

    split = args.out / f"torchrun-{ranks}"
    per_rank = max(1, args.threads // ranks)
    env = dict(os.environ, OMP_NUM_THREADS=str(per_rank), MKL_NUM_THREADS=str(per_rank))
    torchrun = [str(Path(sys.executable).with_name("torchrun")), "--nnodes", str(args.nnodes), "--nproc-per-node",
                str(args.nproc_per_node)]
    module = ["-m", "neuras_distill.cli", *args.run, "--quiet", "--out", str(split)]
    if args.nnodes == 1:
        procs = [subprocess.Popen([*torchrun, "--standalone", *module], env=env)]
    else:
        port = _free_port()
        procs = [subprocess.Popen([*torchrun, "--node-rank", str(n), "--master-addr", "127.0.0.1", "--master-port",
                                   str(port), *module], env=env) for n in range(args.nnodes)]
    codes = [p.wait() for p in procs]
    if any(codes):
        raise SystemExit(f"torchrun exited with {codes}")
    second = _report(split)
    print(json.dumps({"run": f"torchrun {args.nnodes} nodes x {args.nproc_per_node}", "threads_per_rank": per_rank,
                      **second}), flush=True)
    print(json.dumps({"ratio_split_over_one": {k: round(second["stage_seconds"][k] / v, 3)
                                               for k, v in first["stage_seconds"].items() if v > 0},
                      "total_ratio": round(second["distill_seconds"] / first["distill_seconds"], 3),
                      "psnr_difference_db": second["psnr"] - first["psnr"]}))


if __name__ == "__main__":
    main()
