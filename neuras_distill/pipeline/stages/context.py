"""What every stage of a run shares: the field, the configuration, the work area, the clock and the record of
decisions (:class:`RunContext`)."""

from __future__ import annotations

import json
import time
import zlib
from dataclasses import asdict, dataclass, field as dataclass_field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np
import torch

from ... import __version__
from ...config import DistillConfig
from ...device import peak_memory_mb
from ...device_field import on_device
from ...fields.base import Field
from ...playback.projection import shift_cameras
from ...render.local_frame import LocalFrameField, box_centre
from ..cache import StageCache, field_fingerprint
from ..choices import Background, Decisions
from ..progress import RunProgress

if TYPE_CHECKING:
    from ..parallel import RenderPool

#: The stages of a run, in order (their manifests are ``stages/<name>/manifest.json`` in the run folder).
STAGE_NAMES = ("cameras", "teacher", "geometry", "gbuffer", "distill", "bake", "evaluate")
#: The work area's folder of per-run arrays that are not stored stages (``RunContext.scratch_array``).
SCRATCH = "scratch"


def seed_stage(seed: int, stage: str) -> None:
    """Seed torch and numpy from the run's seed and the stage's name, so a stage's result does not depend on
    whether the stages before it ran or were reused."""
    s = (int(seed) * 1_000_003 + zlib.crc32(stage.encode())) % 2**31
    torch.manual_seed(s)
    np.random.seed(s)


class StageClock:
    """Announces, seeds and times the stages; writes each one's manifest into ``<root>/stages/<name>/``.

    ``peak_rss_mb``: the process's peak resident memory (MB) when each stage ended; it never falls, so the stage
    where it rises is the one that set the run's peak (a stored stage that was reused adds little)."""

    def __init__(self, root: Path | None, log: Callable[[str], None], seed: int = 0, display: RunProgress | None = None):
        self.root, self.log, self.seed = root, log, seed
        self.display = display or RunProgress(False, STAGE_NAMES)
        self.seconds: dict[str, float] = {}
        self.peak_rss_mb: dict[str, float] = {}
        self._name, self._t0 = "", 0.0
        self._started = time.perf_counter()

    def elapsed(self) -> float:
        """Seconds since the run's stages began (what a run budget has spent)."""
        return time.perf_counter() - self._started

    def start(self, name: str, what: str) -> None:
        self.log(f"[{STAGE_NAMES.index(name) + 1}/{len(STAGE_NAMES)}] {name}: {what}")
        self._name, self._t0 = name, time.perf_counter()
        self.display.start(name)
        seed_stage(self.seed, name)

    @property
    def current(self) -> str | None:
        """The stage started last (None before the first)."""
        return self._name or None

    def done(self, **info) -> float:
        seconds = time.perf_counter() - self._t0
        self.seconds[self._name] = round(seconds, 3)
        self.peak_rss_mb[self._name] = round(peak_memory_mb()["peak_rss_mb"], 1)
        if self.root is not None:
            folder = self.root / "stages" / self._name
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "manifest.json").write_text(json.dumps(
                {"stage": self._name, "version": __version__, "seconds": seconds,
                 "peak_rss_mb": self.peak_rss_mb[self._name], **info}, indent=2, default=str))
        return seconds


def settings(section, drop: tuple = ()) -> dict:
    """A config section as a dict for cache keys, without the settings that do not change results."""
    return {k: v for k, v in asdict(section).items() if k not in drop}


@dataclass
class RunContext:
    """One run's shared state.

    Attributes:
        field: the field being distilled (world coordinates).
        cfg: the validated configuration (the stability check may have raised some settings).
        root: the run folder being written (hidden until the run finishes), None when nothing is written.
        cache: the work area, None without a run folder.
        log: one line to the user; progress: whether to draw the run's progress display (``display``, a
            :class:`~neuras_distill.pipeline.progress.RunProgress` the clock starts at each stage).
        clock: stage announcements, seeds and times; decisions: what was kept and left out, in order.
        keys: each stored stage's key (``pipeline.cache.digest``), filled in as the stages run.
        device: where the field, the teacher and training compute (``neuras_distill.device``); on a GPU
            ``field`` is replaced by a :class:`~neuras_distill.device_field.DeviceField` after the fingerprint (of the
            host field: the same keys on every device) is taken.
        pool: a :class:`~neuras_distill.pipeline.parallel.RenderPool` sharing the teacher's renders and training
            (``--nproc N``), or None (one process).
        origin: (3,) float64 world position of the run's local frame: the foreground box's centre. Every
            float32 stage (the mesh from marching cubes on, the G-buffers, training, the bundle, the players)
            works relative to it; ``local_field`` and :meth:`local` give the field and cameras in that frame.
    """

    field: Field
    cfg: DistillConfig
    root: Path | None
    cache: StageCache | None
    log: Callable[[str], None]
    progress: bool
    clock: StageClock = None
    decisions: Decisions = dataclass_field(default_factory=Decisions)
    keys: dict = dataclass_field(default_factory=dict)
    device: torch.device = dataclass_field(default_factory=lambda: torch.device("cpu"))
    pool: RenderPool | None = None

    def __post_init__(self) -> None:
        self.display = RunProgress(self.progress, STAGE_NAMES)
        if self.clock is None:
            self.clock = StageClock(self.root, self.log, self.cfg.train.seed, self.display)
        self.fingerprint = field_fingerprint(self.field)
        self.field = on_device(self.field, self.device, self.cfg.teacher.precision)
        self.origin = box_centre(self.field.aabb)
        self.local_field = LocalFrameField(self.field, self.origin)
        self._background: Background | None = None
        self._volume_renderer = None

    @property
    def volume_renderer(self):
        """The run's teacher :class:`~neuras_distill.render.volume.VolumeRenderer` (``teacher.num_steps``,
        ``teacher.far_steps``), built once: its occupancy grid samples the field, which the cameras stage's probes
        and the teacher share."""
        if self._volume_renderer is None:
            from ...render.volume import VolumeRenderer

            self._volume_renderer = VolumeRenderer(self.field, num_steps=self.cfg.teacher.num_steps,
                                                   far_steps=self.cfg.teacher.far_steps,
                                                   occupancy_resolution=self.cfg.teacher.occupancy_resolution)
        return self._volume_renderer

    def local(self, cameras):
        """``cameras`` (world) in the run's local frame (centres minus ``origin``, in float64)."""
        return shift_cameras(cameras, self.origin)

    @property
    def background(self) -> Background:
        """What rays that miss the foreground see, measured once."""
        if self._background is None:
            self._background = Background(self.field)
        return self._background

    def cached(self, stage: str, key: str, compute: Callable[[], Any], save, load) -> Any:
        """The stored result of ``stage`` under ``key`` (``StageCache.cached``), or ``compute()`` without a
        work area; records the key."""
        self.keys[stage] = key
        if self.cache is None:
            return compute()
        return self.cache.cached(stage, key, compute, save, load)

    def cached_files(self, stage: str, key: str, write: Callable[[Path], None], load: Callable[[Path], Any],
                     compute: Callable[[], Any]) -> Any:
        """The stored result of a stage that writes its own files (``StageCache.cached_files``: written by
        ``write(folder)`` and returned as ``load(folder)``, memory-mapped), or ``compute()`` in memory without a
        work area; records the key."""
        self.keys[stage] = key
        if self.cache is None:
            return compute()
        return self.cache.cached_files(stage, key, write, load)

    def scratch_array(self, name: str, shape: tuple, dtype) -> np.ndarray:
        """A writable array of ``shape`` for this run only: memory-mapped from ``<work>/scratch/<name>.npy`` when
        the run has a work area (its pages go back to disk under memory pressure; the folder is pruned with the
        work area's other unkept entries), else in memory."""
        if self.cache is None:
            return np.empty(shape, dtype)
        folder = self.cache.work / SCRATCH
        folder.mkdir(parents=True, exist_ok=True)
        return np.lib.format.open_memmap(folder / f"{name}.npy", mode="w+", dtype=dtype, shape=tuple(shape))

    def progress_printer(self, label: str):
        """A ``(done, total)`` callback counting the current stage's views on the run's display, or None."""
        if not self.progress:
            return None
        return lambda done, total: self.display.count(done, total, f"{label} views")

    def step_counter(self):
        """Training's ``progress``: a ``(step, steps)`` callback counting steps on the run's display, or False."""
        if not self.progress:
            return False
        return lambda step, steps: self.display.count(step, steps, "steps")
