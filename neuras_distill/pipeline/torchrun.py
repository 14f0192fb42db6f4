"""Runs launched by ``torchrun`` (or SLURM's ``srun``) across processes and machines.

Owns: :func:`launch_from_env` (whether this process is one rank of such a launch, and which), :func:`join_group`
(the process group, from the launcher's environment), :func:`agree` (every rank checks that every other one got
the same inputs, or stops with one line naming the rank that did not) and :func:`serve` (what a rank other than 0
does: render and train its share until rank 0 is done; ``parallel.RenderPool.joined`` is rank 0's side).

Launchers: torchrun sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``LOCAL_WORLD_SIZE``, ``MASTER_ADDR`` and
``MASTER_PORT``; ``srun`` sets ``SLURM_PROCID``, ``SLURM_NTASKS`` and ``SLURM_LOCALID`` (the batch script exports
``MASTER_ADDR`` and ``MASTER_PORT``, as for any torch.distributed job under SLURM). A launch of one process is
no launch: the run is a plain one-process run.

Every rank builds the field itself from the same source (a checkpoint path every node can read, or an embedded
scene) and runs the same command; rank 0 alone writes the run folder and the report. The group is gloo; the ranks
are CPU processes (``--device cpu``), as ``--nproc``'s are: data-parallel training exchanges CPU gradients.
:func:`join_group` would form ``"cpu:gloo,cuda:nccl"`` for CUDA ranks, which no run uses yet.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from datetime import timedelta

from ..errors import BadInputError, require

#: Seconds a rank waits for the others at a collective before the run gives up (``parallel.DEFAULT_TIMEOUT_S``).
DEFAULT_TIMEOUT_S = 3600.0


@dataclass(frozen=True)
class Launch:
    """This process's place in a launch: ``rank`` of ``world`` processes, ``local_rank`` of ``local_world`` on its
    node, the node's index (torchrun's ``GROUP_RANK``, SLURM's ``SLURM_NODEID``; None when the launcher does not
    say) and the launcher (``"torchrun"`` or ``"srun"``)."""

    rank: int
    world: int
    local_rank: int
    local_world: int
    launcher: str
    node: int | None = None


def _int(environ, name: str) -> int:
    try:
        return int(environ[name])
    except ValueError:
        raise BadInputError(f"{name}={environ[name]!r} in the environment is not a whole number; launch with "
                            "torchrun or srun, which set it") from None


def launch_from_env(environ=None) -> Launch | None:
    """The launch this process belongs to (torchrun's variables first, then SLURM's), or None outside one or in
    a launch of a single process."""
    environ = os.environ if environ is None else environ
    if "RANK" in environ and "WORLD_SIZE" in environ:
        rank, world, launcher = _int(environ, "RANK"), _int(environ, "WORLD_SIZE"), "torchrun"
        local_rank = _int(environ, "LOCAL_RANK") if "LOCAL_RANK" in environ else 0
        local_world = _int(environ, "LOCAL_WORLD_SIZE") if "LOCAL_WORLD_SIZE" in environ else 1
        node = _int(environ, "GROUP_RANK") if "GROUP_RANK" in environ else None
    elif "SLURM_PROCID" in environ and "SLURM_NTASKS" in environ and "MASTER_ADDR" in environ:
        rank, world, launcher = _int(environ, "SLURM_PROCID"), _int(environ, "SLURM_NTASKS"), "srun"
        local_rank = _int(environ, "SLURM_LOCALID") if "SLURM_LOCALID" in environ else 0
        local_world = _int(environ, "SLURM_NTASKS_PER_NODE") if "SLURM_NTASKS_PER_NODE" in environ else 1
        node = _int(environ, "SLURM_NODEID") if "SLURM_NODEID" in environ else None
    else:
        return None
    if world <= 1:
        return None
    require(0 <= rank < world, f"rank {rank} is outside a launch of {world} processes; check the launcher")
    for name in ("MASTER_ADDR", "MASTER_PORT"):
        require(name in environ, f"{launcher} launched {world} processes but {name} is not set; export it (the "
                                 "address and a free port of the machine running rank 0)")
    return Launch(rank, world, local_rank, local_world, launcher, node)


def join_group(launch: Launch, device: str = "cpu", timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """Form (or join) the process group of ``launch`` from the launcher's environment; nothing when it exists."""
    import torch
    import torch.distributed as dist

    if dist.is_initialized():
        return
    cuda = str(device).startswith("cuda") or (str(device) == "auto" and torch.cuda.is_available())
    if cuda:
        torch.cuda.set_device(launch.local_rank % max(1, torch.cuda.device_count()))
    os.environ.setdefault("RANK", str(launch.rank))
    os.environ.setdefault("WORLD_SIZE", str(launch.world))
    try:
        dist.init_process_group("cpu:gloo,cuda:nccl" if cuda else "gloo", init_method="env://", rank=launch.rank,
                                world_size=launch.world, timeout=timedelta(seconds=timeout_s))
    except Exception as exc:       # the rendezvous failed: an address, a port, a rank that never came
        raise BadInputError(f"rank {launch.rank}: could not join the {launch.world} processes of the launch "
                            f"({type(exc).__name__}: {str(exc).splitlines()[0][:160]}); check MASTER_ADDR and "
                            "MASTER_PORT and start every rank") from None


def agree(launch: Launch, what: dict, error: str | None = None) -> list[dict]:
    """Every rank's ``what`` (settings that must be equal: the field's fingerprint, the configuration, the
    version) and ``error`` (this rank could not get its inputs) gathered on every rank; raises the same one-line
    :class:`BadInputError` on every rank when a rank failed or differs from rank 0. Returns each rank's
    ``{"host", "node"}`` (the node's index, or its host name when the launcher gives none)."""
    import torch.distributed as dist

    host = socket.gethostname()
    mine = {"host": host, "node": host if launch.node is None else launch.node, "error": error, "what": what}
    everyone = [None] * launch.world
    try:
        dist.all_gather_object(everyone, mine)
    except RuntimeError as exc:
        raise BadInputError(f"rank {launch.rank}: another rank stopped before the run started "
                            f"({str(exc).splitlines()[0][:160]}); relaunch every rank") from None
    failed = [(r, e["host"], e["error"]) for r, e in enumerate(everyone) if e["error"]]
    if failed:
        r, host, message = failed[0]
        raise BadInputError(f"rank {r} (on {host}) could not start: {message}")
    for r, e in enumerate(everyone):
        differs = sorted(k for k in set(e["what"]) | set(everyone[0]["what"])
                         if e["what"].get(k) != everyone[0]["what"].get(k))
        if differs:
            raise BadInputError(f"rank {r} (on {e['host']}) has another {' and '.join(differs)} than rank 0; "
                                "launch every rank with the same command, files and version")
    return [{"host": e["host"], "node": e["node"]} for e in everyone]


def serve(field, launch: Launch) -> None:
    """Ranks other than 0: render and train this rank's share of every request of rank 0 until it is done
    (``parallel.serve_requests``); a rank 0 that stops answering ends this rank with one line."""
    import torch.distributed as dist

    from .parallel import serve_requests

    try:
        serve_requests(field, launch.rank, launch.world, take_payload=None)
    except RuntimeError as exc:
        raise BadInputError(f"rank {launch.rank}: rank 0 or another rank stopped answering "
                            f"({str(exc).splitlines()[0][:160]}); relaunch the same command on every node: it "
                            "resumes from the stages rank 0 finished") from None
    finally:
        if dist.is_initialized():
            dist.destroy_process_group()


def leave_group() -> None:
    """Leave the process group if this process is in one (after a failure, before exiting)."""
    import contextlib

    import torch.distributed as dist

    with contextlib.suppress(Exception):
        if dist.is_initialized():
            dist.destroy_process_group()
