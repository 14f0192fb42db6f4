"""Local worker processes that share the field's volume rendering and the training (``--nproc N``; the only
torch.distributed user).

Rank 0 is the run itself; ranks 1 .. N-1 are processes it spawns, each holding a copy of the field (sent once,
pickled by ``torch.multiprocessing``, whose tensors travel through shared memory). A render request is
broadcast to every rank (the cameras, the renderer's settings and its occupancy grid, so no worker rebuilds it);
rank ``r`` renders views ``r, r + N, r + 2N, ...`` and the renders are gathered on rank 0 in view order. Every
rank uses ``cpu_count // N`` torch threads while it renders (2 processes of 1 thread instead of 1 of 2 on this
machine), rank 0 restores its own count afterwards. The group is gloo over TCP on 127.0.0.1. Under torchrun or srun
(``pipeline/torchrun.py``) the same protocol runs across machines: every rank rebuilds the field itself, the group
comes from the launcher's environment (:meth:`RenderPool.joined`), and a fit's arrays travel through the group.

What is split: the teacher's renders of the training views (``stages.teacher``) and training
(:meth:`RenderPool.fit`: data-parallel, every rank runs :func:`~neuras_distill.neural.train.fit` on its share of
each batch and the gradients are summed, ``neural.data_parallel``). The training arrays (G-buffers, teacher
images) and a copy of the model reach the workers once per fit through a ``torch.multiprocessing`` queue, i.e.
shared memory, not the gloo socket. What is not split: the held-out field frames (they are timed one at a time,
as one process, so the field's FPS stays the fair "before" figure).

Failures: a worker that dies or a collective that waits longer than ``timeout_s`` ends the run with one line
(:class:`~neuras_distill.errors.BadInputError`, exit 2) that names ``--nproc 1`` as the way round;
so does a worker that exits while the group forms.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from datetime import timedelta

import numpy as np
import torch

from ..errors import BadInputError, require

#: Seconds a collective operation may wait for the other ranks before the run gives up (a worker's share of a
#: large teacher can take many minutes; a worker that dies is noticed at once, its connection closes).
DEFAULT_TIMEOUT_S = 3600.0


def max_processes() -> int:
    """The most local processes ``--nproc`` accepts: the machine's CPU count."""
    return max(1, os.cpu_count() or 1)


def check_nproc(nproc) -> int:
    """``nproc`` as an int in 1 .. :func:`max_processes`, else one clear error."""
    try:
        n = int(nproc)
    except (TypeError, ValueError):
        raise BadInputError(f"--nproc must be a whole number of processes, got {nproc!r}") from None
    limit = max_processes()
    require(n >= 1, f"--nproc must be at least 1 (1: no worker processes), got {n}")
    require(n <= limit, f"--nproc {n} is more than this machine's {limit} CPUs; use --nproc {limit} or fewer")
    return n


def threads_per_process(nproc: int) -> int:
    """Torch threads each of ``nproc`` processes uses while rendering."""
    return max(1, (os.cpu_count() or 1) // max(1, nproc))


@dataclass
class RenderRequest:
    """What every rank needs to render its share: cameras (``Cameras.to_json``), the ``VolumeRenderer``
    keyword arguments (occupancy grid included) and whether surface / fringe depths are tracked."""
    cameras: dict
    renderer_kwargs: dict
    depths: bool


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _render_share(field, request: RenderRequest, rank: int, world: int) -> list[tuple[int, dict]]:
    """Render views ``rank, rank + world, ...`` of the request: [(view index, {rgb, opacity, depths...})]."""
    from ..render.cameras import Cameras
    from ..render.volume import VolumeRenderer

    cameras = Cameras.from_json(request.cameras)
    renderer = VolumeRenderer(field, **request.renderer_kwargs)
    out = []
    for i in range(rank, len(cameras), world):
        r = renderer.render(cameras, i, crossings=request.depths)
        out.append((i, {k: np.asarray(v) for k, v in r.items()}))
    return out


@dataclass
class FitRequest:
    """Tells the workers to train with rank 0: on the :class:`FitPayload` it carries (ranks of a torchrun launch,
    on other machines), or on the one waiting in their queue (spawned workers: shared memory)."""
    payload: object = None


@dataclass
class FitPayload:
    """What a worker trains on: a copy of the model (and skybox), the arrays of
    :func:`~neuras_distill.neural.train.fit` as tensors (shared memory), its keyword arguments, and the
    training checkpoint's stored state when rank 0 resumes from one."""
    model: object
    skybox: object
    arrays: dict
    kwargs: dict
    stored: dict | None


@dataclass
class Abort:
    """Tells the ranks of a torchrun / srun launch that rank 0 stopped, and why (one line)."""
    message: str


class _StoredState:
    """The part of ``TrainCheckpoint`` a worker's ``fit`` uses: rank 0's stored state, never due, never saved."""

    saved = 0

    def __init__(self, state):
        self._state = state

    def load(self):
        return self._state

    def due(self) -> bool:
        return False


def _fit_share(payload: FitPayload, rank: int, world: int) -> float:
    """Rank ``rank``'s part of a data-parallel fit (its model copy is dropped afterwards); its seconds."""
    import time

    from ..neural.data_parallel import GradientExchange
    from ..neural.train import fit
    from ..neural.train_batches import TrainingPixels

    t0 = time.perf_counter()
    a = payload.arrays
    fit(payload.model, TrainingPixels(**a), skybox=payload.skybox, progress=False,
        checkpoint=_StoredState(payload.stored) if payload.stored is not None else None,
        exchange=GradientExchange(rank, world), **payload.kwargs)
    return time.perf_counter() - t0


def serve_requests(field, rank: int, world: int, take_payload) -> None:
    """Ranks 1 .. world-1 of a formed group: serve rank 0's render and fit requests until it sends None. A fit's
    payload comes with the request or from ``take_payload()``; after each request the rank's seconds go back to
    rank 0 with its share."""
    import time

    import torch.distributed as dist

    while True:
        box = [None]
        dist.broadcast_object_list(box, src=0)
        request = box[0]
        if request is None:
            break
        if isinstance(request, Abort):
            raise BadInputError(f"rank {rank}: rank 0 stopped: {request.message}")
        if isinstance(request, FitRequest):
            seconds = _fit_share(request.payload if request.payload is not None else take_payload(), rank, world)
            dist.gather_object(seconds, None, dst=0)
            continue
        t0 = time.perf_counter()
        with torch.no_grad():
            share = _render_share(field, request, rank, world)
        dist.gather_object((share, time.perf_counter() - t0), None, dst=0)


def _worker(index: int, field, world: int, port: int, timeout_s: float, queues) -> None:
    """Ranks 1 .. world-1 of ``--nproc``: join the group, then serve render and fit requests until told to stop."""
    import torch.distributed as dist

    rank = index + 1
    torch.set_num_threads(threads_per_process(world))
    store = dist.TCPStore("127.0.0.1", port, world, is_master=False, timeout=timedelta(seconds=timeout_s))
    store.set(f"ready{rank}", "1")
    dist.init_process_group("gloo", store=store, rank=rank, world_size=world, timeout=timedelta(seconds=timeout_s))
    try:
        serve_requests(field, rank, world, queues[index].get)
    finally:
        dist.destroy_process_group()
    exit_rank(0)


def exit_rank(code: int) -> None:
    """End this process (a rank of a group) with ``code`` now, its output flushed, without the interpreter's
    shutdown. gloo's worker threads may still be releasing the last collective's tensors, which takes the GIL;
    a thread that asks for the GIL while the interpreter shuts down is unwound, and the unwinding aborts the
    process (SIGABRT, "terminate called without an active exception") after its work is done."""
    import contextlib
    import sys

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


class RenderPool:
    """``nproc`` processes that render a field's views and train together: this one and ``nproc - 1`` spawned
    workers (``--nproc``), or rank 0 of a torchrun / srun launch whose other ranks run
    :func:`~neuras_distill.pipeline.torchrun.serve` on their own machines (:meth:`joined`).

    Use as a context manager; :meth:`render_views` has the contract of
    :func:`neuras_distill.pipeline.evaluate.render_field_views` (renders in view order, per-view seconds);
    :meth:`ranks` is what the report says about the processes.
    """

    def __init__(self, field, nproc: int, timeout_s: float = DEFAULT_TIMEOUT_S):
        import torch.distributed as dist
        import torch.multiprocessing as mp

        self.nproc = check_nproc(nproc)
        require(self.nproc >= 2, "a RenderPool needs at least 2 processes")
        self.timeout_s = float(timeout_s)
        self.launcher, self.places = "--nproc", [{"host": socket.gethostname(), "node": 0}] * self.nproc
        self.threads = threads_per_process(self.nproc)
        self._seconds = {"teacher": [0.0] * self.nproc, "training": [0.0] * self.nproc}
        port = _free_port()
        self._queues = [mp.get_context("spawn").SimpleQueue() for _ in range(self.nproc - 1)]
        self._store = dist.TCPStore("127.0.0.1", port, self.nproc, is_master=True,
                                    timeout=timedelta(seconds=self.timeout_s), wait_for_workers=False)
        try:
            self._context = mp.start_processes(_worker, args=(field, self.nproc, port, self.timeout_s, self._queues),
                                               nprocs=self.nproc - 1, join=False, start_method="spawn")
        except Exception as exc:   # the field could not be sent (e.g. it holds a local function)
            raise BadInputError(f"--nproc {self.nproc}: the field cannot be sent to worker processes "
                                f"({type(exc).__name__}: {exc}); run with --nproc 1") from None
        self._join_group(dist, port)
        self._dist = dist

    @classmethod
    def joined(cls, launch, places: list[dict], timeout_s: float = DEFAULT_TIMEOUT_S) -> "RenderPool":
        """Rank 0's pool in the process group of a torchrun / srun ``launch`` (``torchrun.Launch``, the group
        already formed; ``places``: each rank's ``{"host", "node"}``, ``torchrun.agree``). Fit payloads travel
        through the group (the ranks may be on other machines); every process keeps the torch threads it was
        launched with."""
        import torch.distributed as dist

        pool = cls.__new__(cls)
        pool.nproc, pool.timeout_s, pool.launcher, pool.places = launch.world, float(timeout_s), launch.launcher, places
        pool.threads = torch.get_num_threads()
        pool._seconds = {"teacher": [0.0] * launch.world, "training": [0.0] * launch.world}
        pool._queues, pool._context, pool._store, pool._dist = None, None, None, dist
        return pool

    def ranks(self) -> dict:
        """``report.json["ranks"]``: the launcher, how many ranks on how many nodes, each rank's host and its
        seconds of teacher rendering and of training."""
        return {"launcher": self.launcher, "ranks": self.nproc, "nodes": self.nodes(),
                "hosts": [p["host"] for p in self.places],
                "teacher_seconds": [round(x, 3) for x in self._seconds["teacher"]],
                "training_seconds": [round(x, 3) for x in self._seconds["training"]]}

    def nodes(self) -> int:
        """How many nodes (machines, or torchrun's node groups) the ranks run on."""
        return len({str(p["node"]) for p in self.places})

    def _join_group(self, dist, port: int) -> None:
        """Wait until every worker has reached the store (each sets ``ready<rank>``), watching them meanwhile: one
        that exits first (it could not import or unpickle something) ends the wait at once instead of after
        ``timeout_s``; then form the group, which no longer waits on anyone."""
        import time

        keys = [f"ready{r}" for r in range(1, self.nproc)]
        while not self._store.check(keys):
            dead = [p.exitcode for p in self._context.processes if p.exitcode is not None]
            if dead:
                self._kill()
                raise BadInputError(f"--nproc {self.nproc}: a worker process exited while starting (exit code "
                                    f"{dead[0]}); run with --nproc 1")
            time.sleep(0.05)
        try:
            dist.init_process_group("gloo", store=self._store, rank=0, world_size=self.nproc,
                                    timeout=timedelta(seconds=self.timeout_s))
        except Exception as exc:
            self._kill()
            raise BadInputError(f"--nproc {self.nproc}: the worker processes did not start "
                                f"({type(exc).__name__}: {str(exc).splitlines()[0][:160]}); "
                                f"run with --nproc 1") from None

    def render_views(self, renderer, cameras, progress=None, *, depths: bool = False):
        """Every camera rendered once, split over the ranks: a ``FieldRenders`` in view order (``seconds``:
        each view's render time on the rank that rendered it, while the others rendered theirs)."""
        import time

        from ..render.field_renders import FieldRenders

        request = RenderRequest(cameras.to_json(), renderer_settings(renderer), depths)
        old = torch.get_num_threads()
        torch.set_num_threads(self.threads)
        t0 = time.perf_counter()
        try:
            self._dist.broadcast_object_list([request], src=0)
            with torch.no_grad():
                own = _render_share(renderer.world_field, request, 0, self.nproc)
            shares = [None] * self.nproc
            self._dist.gather_object((own, time.perf_counter() - t0), shares, dst=0)
        except RuntimeError as exc:
            self._kill()
            raise BadInputError(self._failure("rendering the teacher's views", exc)) from None
        finally:
            torch.set_num_threads(old)
        wall = time.perf_counter() - t0
        for r, (_, seconds) in enumerate(shares):
            self._seconds["teacher"][r] += seconds
        views = dict(item for share, _ in shares for item in share)
        require(sorted(views) == list(range(len(cameras))), "--nproc: the workers returned an incomplete set of views")
        renders = FieldRenders([], [], [], [], [])
        for i in range(len(cameras)):
            out = views[i]
            renders.images.append(out["rgb"])
            renders.opacities.append(out["opacity"])
            if depths:
                renders.surface_depths.append(out["surface_depth"])
                renders.fringe_depths.append(out["fringe_depth"])
            renders.seconds.append(wall / len(cameras))   # wall time per view of the whole split render
        if progress is not None:
            progress(len(cameras), len(cameras))
        return renders

    def fit(self, model, views, *, skybox=None, checkpoint=None, progress: bool = True, **kwargs):
        """:func:`neuras_distill.neural.train.fit` on every rank at once, each computing its share of every
        batch (the arguments are ``fit``'s; the G-buffers and targets stay on the CPU). Returns rank 0's
        ``TrainLog``; ``model`` and ``skybox`` are trained in place as by ``fit``."""
        import copy
        import time

        from ..neural.data_parallel import GradientExchange
        from ..neural.train import fit

        kwargs = dict(kwargs)
        kwargs["num_threads"] = self.threads
        require(kwargs.get("device") in (None, "cpu") or torch.device(kwargs["device"]).type == "cpu",
                f"--nproc {self.nproc} trains on CPU processes; on {kwargs.get('device')} use --nproc 1")
        arrays = {name: getattr(views, name) for name in ("uv", "coverage", "dirs", "targets", "origins", "sky_pixels")
                  if getattr(views, name) is not None}
        shared = {k: _shared_tensor(v) for k, v in arrays.items()}
        stored = checkpoint.load() if checkpoint is not None else None
        try:
            if self._queues is None:        # other machines: the payload travels with the request
                payload = FitPayload(copy.deepcopy(model), copy.deepcopy(skybox), shared, kwargs, stored)
                self._dist.broadcast_object_list([FitRequest(payload)], src=0)
            else:
                for queue in self._queues:  # first the payloads (small: handles to shared memory), then the call
                    queue.put(FitPayload(copy.deepcopy(model), copy.deepcopy(skybox), shared, kwargs, stored))
                self._dist.broadcast_object_list([FitRequest()], src=0)
            t0 = time.perf_counter()
            log = fit(model, views, skybox=skybox, checkpoint=checkpoint, progress=progress,
                      exchange=GradientExchange(0, self.nproc), **kwargs)
            seconds = [None] * self.nproc
            self._dist.gather_object(time.perf_counter() - t0, seconds, dst=0)
        except RuntimeError as exc:
            self._kill()
            raise BadInputError(self._failure("training", exc)) from None
        for r, s in enumerate(seconds):
            self._seconds["training"][r] += float(s)
        return log

    def _failure(self, doing: str, exc: Exception) -> str:
        """The one line that ends a run whose other ranks failed or stopped answering while ``doing``."""
        why = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        if self._queues is None:
            return (f"rank 0: another rank (of {self.nproc} on {self.nodes()} nodes) failed or did not "
                    f"answer within {self.timeout_s:.0f} s while {doing} ({why}); relaunch the same command on "
                    "every node: it resumes from the finished stages")
        return (f"--nproc {self.nproc}: a worker process failed or did not answer within {self.timeout_s:.0f} s "
                f"while {doing} ({why}); run with --nproc 1")

    def close(self) -> None:
        """Tell the workers to stop, leave the group and wait for them (spawned ones)."""
        if getattr(self, "_dist", None) is None:
            return
        try:
            self._dist.broadcast_object_list([None], src=0)
            self._dist.destroy_process_group()
            if self._context is not None:
                self._context.join(timeout=60)
        except Exception:
            self._kill()
        self._dist = None

    def _kill(self) -> None:
        for p in getattr(getattr(self, "_context", None), "processes", []):
            if p.is_alive():
                p.kill()
        import contextlib

        import torch.distributed as dist

        with contextlib.suppress(Exception):   # best effort: the group may be half-formed or already broken
            if dist.is_initialized():
                dist.destroy_process_group()
        self._dist = None

    def __enter__(self):
        return self

    def __exit__(self, kind, exc, tb):
        if exc is not None and self._queues is None and getattr(self, "_dist", None) is not None:
            # ranks on other machines: tell them why rank 0 stopped, so each ends with the same line
            import contextlib

            with contextlib.suppress(Exception):
                self._dist.broadcast_object_list([Abort(str(exc).splitlines()[0] if str(exc) else kind.__name__)],
                                                 src=0)
                self._dist.destroy_process_group()
            self._dist = None
        self.close()


def _shared_tensor(array) -> torch.Tensor:
    """A torch-owned copy of ``array`` (numpy or tensor, on the host) that the queue moves to shared memory."""
    t = array if torch.is_tensor(array) else torch.from_numpy(np.ascontiguousarray(array))
    return t.detach().cpu().clone()


def renderer_settings(renderer) -> dict:
    """The keyword arguments that rebuild ``renderer`` (a ``VolumeRenderer``) on another rank, its occupancy
    grid included (moved to the host)."""
    occupancy = renderer.occupancy.to("cpu") if renderer.occupancy is not None else None
    return {"num_steps": renderer.num_steps, "chunk": renderer.chunk, "occupancy": occupancy,
            "early_stop": renderer.early_stop, "segment": renderer.segment, "min_weight": renderer.min_weight,
            "device": "cpu", "far_steps": renderer.far_steps}
