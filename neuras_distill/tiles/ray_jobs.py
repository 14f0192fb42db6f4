"""Every unfinished tile as a Ray task: ``neuras-distill tiles run CITY --ray [ADDRESS]`` (this module owns every
Ray call).

Ray (``pip install neuras-distill[ray]``) is an optional extra: one machine never needs it (``tiles run`` runs the
tiles in turn; a SLURM array runs ``--tile $SLURM_ARRAY_TASK_ID``). Without ADDRESS a local Ray starts on this
machine and stops with the command; with ADDRESS (``host:port`` of ``ray start --head``, or ``auto``) the tasks go
to that cluster, which must see CITY at the same path (a shared file system).

Each task is :func:`~.run.run_tile` of one tile: CPUs ``--nproc`` (its own processes when above 1), one GPU with
``--device cuda``, and torch's threads set to its CPUs so a tile's bundle does not depend on which worker ran it
(with fixed ``--steps``, the bytes are those of the sequential loop run with as many threads). A task whose worker
dies (killed, out of memory, a lost node) is retried :data:`RETRIES` times; a tile's run folder resumes what the
dead attempt finished, and a tile's files appear only when complete, so a retry cannot leave half a tile. An
error of the tile itself (bad input) is not retried: it is the first error reported. Progress: a line each time a
tile finishes, with how many of the total are done.
"""

from __future__ import annotations

import socket
import time
from pathlib import Path

from ..errors import BadInputError, require

#: Times a task is run again after its worker process died.
RETRIES = 2
#: Seconds the address of ``--ray ADDRESS`` has to accept a connection, and to answer as a Ray cluster.
CONNECT_TIMEOUT_S, PROBE_TIMEOUT_S = 5.0, 60.0


def _ray():
    try:
        import ray  # noqa: PLC0415
    except ImportError:
        raise BadInputError("--ray needs Ray (pip install neuras-distill[ray]); without --ray the tiles run in turn "
                            "on this machine") from None
    return ray


def check_address(address: str) -> None:
    """BadInputError unless ``host:port`` accepts a TCP connection within :data:`CONNECT_TIMEOUT_S`."""
    host, sep, port = address.rpartition(":")
    require(bool(sep) and port.isdigit() and host,
            f"--ray {address!r} is not host:port (the address `ray start --head` prints), nor auto")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise BadInputError(f"--ray {address}: nothing answers there ({exc.strerror or exc}); start the cluster "
                            "with `ray start --head` and pass the address it prints, or leave ADDRESS out for a "
                            "local Ray") from None


def probe_cluster(address: str) -> dict:
    """The cluster's resources ({"CPU": n, "GPU": m, ...}) as a Ray client at ``address`` sees them; asked in a
    child process with a time limit (Ray's own client waits for minutes on an address that accepts connections
    but is not a Ray cluster). BadInputError when it does not answer as one."""
    import json
    import subprocess
    import sys

    code = ("import json, sys, ray; ray.init(address=sys.argv[1], logging_level='ERROR', log_to_driver=False); "
            "print(json.dumps(ray.cluster_resources())); ray.shutdown()")
    hint = ("start the cluster with `ray start --head` and pass the address it prints, or leave ADDRESS out for a "
            "local Ray")
    try:
        out = subprocess.run([sys.executable, "-c", code, address], capture_output=True, text=True,
                             timeout=PROBE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise BadInputError(f"--ray {address}: no Ray cluster answered there within {PROBE_TIMEOUT_S:.0f} s; "
                            f"{hint}") from None
    lines = out.stdout.strip().splitlines()
    try:
        resources = json.loads(lines[-1]) if out.returncode == 0 and lines else None
    except ValueError:
        resources = None
    if not isinstance(resources, dict):
        refused = "InvalidAuthToken" in out.stderr or "Authentication token" in out.stderr
        raise BadInputError(f"--ray {address}: " + ("the cluster asks for its token: set RAY_AUTH_MODE=token (and "
                                                     "RAY_AUTH_TOKEN or ~/.ray/auth_token) as its nodes have it"
                                                     if refused else f"it did not answer as a Ray cluster; {hint}"))
    return resources


def _attempts_file(city: Path, index: int) -> Path:
    """Where a tile's task counts its attempts (a line each), beside the tiles' folders."""
    return Path(city) / "tiles" / f".ray-attempts-{index}"


def _tile_task(city: str, index: int, device: str, nproc: int, threads: int) -> tuple[int, str, int]:
    """One tile on a Ray worker: its attempt counted, torch's threads fixed, then :func:`run_tile` quietly;
    (index, status, attempts)."""
    import torch

    from .run import run_tile

    counter = _attempts_file(Path(city), index)
    counter.parent.mkdir(parents=True, exist_ok=True)
    with counter.open("a") as f:
        f.write("attempt\n")
    torch.set_num_threads(max(1, int(threads)))
    status = run_tile(city, index, device=device, nproc=nproc, log=lambda m: None, progress=False)
    attempts = len(counter.read_text().splitlines())
    counter.unlink(missing_ok=True)
    return index, status, attempts


def run_tiles_on_ray(city, address: str | None = None, *, device: str = "cpu", nproc: int = 1, log=None) -> dict:
    """Every unfinished tile of the plan in ``city`` as a Ray task; {index: "done" | "skipped"}."""
    from .plan import read_plan
    from .run import tile_done

    city = Path(city).resolve()
    plan = read_plan(city)
    say = log or (lambda m: None)
    ray = _ray()
    if address not in (None, "", "auto"):
        check_address(address)
        resources = probe_cluster(address)
        say(f"ray: the cluster at {address} has {resources.get('CPU', 0):g} CPUs and {resources.get('GPU', 0):g} GPUs")
    todo = [t["index"] for t in plan["tiles"] if not tile_done(city, plan, t["index"])]
    out = {t["index"]: "skipped" for t in plan["tiles"] if t["index"] not in todo}
    total = len(plan["tiles"])
    if not todo:
        say(f"all {total} tiles finished before; nothing to run")
        return out
    gpus = 1 if str(device).startswith("cuda") else 0
    started = not ray.is_initialized()
    if started:
        ray.init(address=address or None, include_dashboard=False, log_to_driver=False, logging_level="ERROR",
                 configure_logging=True)
    try:
        where = address or "a local Ray"
        say(f"ray: {len(todo)} of {total} tiles as tasks on {where} ({max(1, nproc)} CPUs"
            + (", 1 GPU" if gpus else "") + " each)")
        task = ray.remote(num_cpus=max(1, nproc), num_gpus=gpus, max_retries=RETRIES,
                          retry_exceptions=False)(_tile_task)
        pending = {task.remote(str(city), k, str(device), nproc, max(1, nproc)): k for k in todo}
        t0 = time.perf_counter()
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            ref = ready[0]
            k = pending.pop(ref)
            try:
                index, status, attempts = ray.get(ref)
            except ray.exceptions.RayTaskError as exc:
                cause = exc.cause if isinstance(getattr(exc, "cause", None), BadInputError) else None
                for other in pending:
                    ray.cancel(other, force=True)
                if cause is not None:
                    raise BadInputError(f"tile {k}: {cause}") from None
                raise
            except ray.exceptions.WorkerCrashedError:
                for other in pending:
                    ray.cancel(other, force=True)
                raise BadInputError(f"tile {k}: its worker died {RETRIES + 1} times (out of memory?); run it alone "
                                    f"with `tiles run {city} --tile {k}` to see why") from None
            out[index] = status
            again = f", after {attempts} attempts (its worker died; Ray ran it again)" if attempts > 1 else ""
            say(f"tile {index}: {status} ({len(out)}/{total} tiles, {time.perf_counter() - t0:.0f} s{again})")
    finally:
        if started:
            ray.shutdown()
    return dict(sorted(out.items()))


__all__ = ["CONNECT_TIMEOUT_S", "RETRIES", "check_address", "run_tiles_on_ray"]
