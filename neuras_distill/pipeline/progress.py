"""One progress display over a whole run (this module owns :class:`RunProgress`).

A single ``tqdm.auto`` bar (a terminal line, or a widget in a notebook) that every stage reuses: it shows
the stage (``[k/7] name``), what the stage counts (the teacher's and the evaluation's views, training's
steps), the run's elapsed time and its ETA. The ETA adds what is left of the counted part of the current
stage (at its measured rate) to the plan's figures for the stages still to come:

* the teacher: its views times the first view's seconds, once a view is done;
* distill: the training plan's steps at the probed steps per second, or its time budget;
* evaluate: the plan's ``eval_seconds`` (the held-out views' pixels at the teacher's measured cost).

The geometry and G-buffer stages have no figure in the plan (nor the short cameras and bake stages); their
time is shown as it passes, and the ETA is marked ``+`` while geometry or the G-buffers are still to come.
The bar is redrawn at most every :data:`REDRAW_S` seconds (on a terminal; :data:`REDRAW_LOG_S` into a file
or a CI log) and at every stage's start. Messages (``neuras_distill.logs``) print above
the bar. Disabled (``progress=False``, ``--quiet``, ranks other than 0), every method does nothing.
"""

from __future__ import annotations

import sys
import time

#: Seconds between redraws on a terminal and into a file or log.
REDRAW_S, REDRAW_LOG_S = 0.5, 15.0


def _clock(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rest = divmod(seconds, 3600)
    return f"{h}:{rest // 60:02d}:{rest % 60:02d}" if h else f"{rest // 60:02d}:{rest % 60:02d}"


class RunProgress:
    """The run's progress bar and ETA.

    Args:
        enabled: draw the bar (False: a silent object).
        stages: the run's stage names in order (``STAGE_NAMES``).
    """

    #: Stages whose seconds the plan does not estimate.
    UNPLANNED = ("geometry", "gbuffer")

    def __init__(self, enabled: bool, stages: tuple[str, ...]):
        self.stages = stages
        self.expected: dict[str, float] = {}
        self._bar = None
        self._stage, self._t_stage, self._t_run = "", 0.0, time.perf_counter()
        self._done, self._total, self._unit, self._t_first = 0, 0, "", None
        self._interval, self._drawn = (REDRAW_S if sys.stderr.isatty() else REDRAW_LOG_S), -1e9
        if enabled:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=None, file=sys.stderr, leave=False, ncols=100, bar_format="{desc} {bar:12} {postfix}")

    # ------------------------------------------------------------------ what the run tells it
    def start(self, stage: str) -> None:
        """A stage begins (``StageClock.start``)."""
        self._stage, self._t_stage = stage, time.perf_counter()
        self._done, self._total, self._unit, self._t_first = 0, 0, "", None
        self._draw(force=True)

    def expect(self, stage: str, seconds: float | None) -> None:
        """The plan's estimate of ``stage``'s seconds (None: no estimate)."""
        if seconds is not None and seconds >= 0:
            self.expected[stage] = float(seconds)
            self._draw()

    def count(self, done: int, total: int, unit: str) -> None:
        """``done`` of ``total`` ``unit`` (views, steps) of the current stage; the teacher's first view sets its
        estimate."""
        now = time.perf_counter()
        if self._t_first is None and done > 0:
            self._t_first = now
            if self._stage == "teacher":
                self.expect("teacher", (now - self._t_stage) * total / done)
        self._done, self._total, self._unit = int(done), int(total), unit
        self._draw()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    # ------------------------------------------------------------------ the ETA
    def eta(self) -> tuple[float | None, bool]:
        """(seconds left by the plan's figures or None before any, whether an unplanned stage is still to come)."""
        if self._stage not in self.stages:
            return None, True
        now = time.perf_counter()
        index = self.stages.index(self._stage)
        left, known = 0.0, False
        if self._total and self._done:
            rate = (now - self._t_stage) / self._done
            left, known = rate * (self._total - self._done), True
        elif self._stage in self.expected:
            left, known = max(0.0, self.expected[self._stage] - (now - self._t_stage)), True
        unplanned = False
        for stage in self.stages[index + 1:]:
            if stage in self.expected:
                left, known = left + self.expected[stage], True
            elif stage in self.UNPLANNED:
                unplanned = True
        return (left if known else None), unplanned

    def _draw(self, force: bool = False) -> None:
        now = time.perf_counter()
        if self._bar is None or (not force and now - self._drawn < self._interval):
            return
        self._drawn = now
        k = self.stages.index(self._stage) + 1 if self._stage in self.stages else 0
        self._bar.set_description_str(f"[{k}/{len(self.stages)}] {self._stage}", refresh=False)
        if self._total:
            self._bar.total, self._bar.n = self._total, self._done
        else:
            self._bar.total, self._bar.n = None, 0
        left, unplanned = self.eta()
        counted = f"{self._done}/{self._total} {self._unit}, " if self._total else ""
        eta = "ETA after the first view" if left is None else f"ETA {_clock(left)}{'+' if unplanned else ''}"
        self._bar.set_postfix_str(f"{counted}stage {_clock(now - self._t_stage)}, run {_clock(now - self._t_run)}, "
                                  f"{eta}", refresh=False)
        self._bar.refresh()
