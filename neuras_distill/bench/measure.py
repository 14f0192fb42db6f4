"""The bench's points: error against the field and time per frame, on the run's held-out cameras.

Every point at a resolution is scored against the same reference: the field marched with twice the steps of
its densest point (``reference_steps``), on every held-out view. Errors are means over the views of PSNR, SSIM
(``metrics``) and FLIP (``flip_metric``, 0 = identical).

Timing: the field (torch, this machine's CPU or GPU) renders each view once per step count after one warm-up
frame, the step counts interleaved view by view; its point is the median over the views, with the 10th-90th
percentile spread. GL frames (bundles and the plain-texture floor) are timed by ``BundleRenderer.time_frames``
(``ctx.finish()`` before each clock stop) in 3 rounds interleaved over the bundles, 3 warm-up frames per round,
>= 30 frames in all cycling through the views: median and 10th-90th percentiles of the pooled frames.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .. import metrics
from ..flip_metric import flip
from ..render.far_region import far_steps_at

if TYPE_CHECKING:
    from ..fields.base import Field


@dataclass
class Reference:
    """The field's renders every point at one resolution is scored against: images (V, H, W, 3) float32."""

    steps: int
    images: list


def scores(images: list, reference: Reference) -> dict:
    """Mean PSNR / SSIM / FLIP of ``images`` (one per held-out view) against the reference renders."""
    psnr = [metrics.psnr(a, b) for a, b in zip(images, reference.images)]
    ssim = [metrics.ssim(a, b) for a, b in zip(images, reference.images)]
    flips = [flip(a, b)[0] for a, b in zip(images, reference.images)]
    return {"psnr": float(np.mean(psnr)), "ssim": float(np.mean(ssim)), "flip": float(np.mean(flips)),
            "psnr_per_view": [float(x) for x in psnr]}


def _spread_ms(seconds) -> dict:
    ms = 1000.0 * np.asarray(seconds, np.float64)
    return {"median_ms": float(np.median(ms)), "p10_ms": float(np.percentile(ms, 10)),
            "p90_ms": float(np.percentile(ms, 90)), "frames": int(ms.size)}


def render_reference(field: Field, cameras, steps: int, progress=None, far_ratio: float = 0.0) -> Reference:
    """The field at ``steps`` per box diagonal (and its far region, ``far_steps``) on every camera (not timed)."""
    from ..render.volume import VolumeRenderer

    renderer = VolumeRenderer(field, num_steps=int(steps), far_steps=far_steps_at(int(steps), far_ratio))
    images = []
    for i in range(len(cameras)):
        images.append(renderer.render(cameras, i)["rgb"])
        if progress:
            progress()
    return Reference(int(steps), images)


def field_points(field: Field, cameras, steps: list[int], reference: Reference, progress=None,
                 far_ratio: float = 0.0) -> list[dict]:
    """The field marched with each of ``steps``: scored and timed on every camera. One warm-up frame per step
    count, then the step counts interleaved view by view, so that a drift of the machine's speed (other
    processes, the CPU's clock) falls on every point alike instead of on whichever ran last."""
    from ..render.volume import VolumeRenderer

    renderers = [VolumeRenderer(field, num_steps=int(s), far_steps=far_steps_at(int(s), far_ratio)) for s in steps]
    for r in renderers:
        r.render(cameras, 0)
    images = [[] for _ in steps]
    seconds = [[] for _ in steps]
    for i in range(len(cameras)):
        for k, r in enumerate(renderers):
            t0 = time.perf_counter()
            images[k].append(r.render(cameras, i)["rgb"])
            seconds[k].append(time.perf_counter() - t0)
            if progress:
                progress()
    points = []
    for s, imgs, secs in zip(steps, images, seconds):
        timing = _spread_ms(secs)
        points.append({"label": f"field, {s} steps", "kind": "field", "steps": int(s),
                       "seconds_per_frame": timing["median_ms"] / 1000.0, "timing": timing, **scores(imgs, reference)})
    return points


@dataclass
class GLEntry:
    """One bundle to play at a bench point: its label, kind ("bundle" | "plain-texture") and extra fields."""

    label: str
    kind: str
    bundle: object
    extra: dict


def gl_points(entries: list[GLEntry], cameras, reference: Reference, *, frames: int = 30, rounds: int = 3,
              progress=None) -> list[dict]:
    """Bundles (and the plain-texture floor) played by ``BundleRenderer``: scored on every camera, then timed
    in ``rounds`` interleaved rounds (each bundle ``ceil(frames / rounds)`` frames after 3 warm-up frames per
    round, ``ctx.finish()`` before each clock stop); each point's median and spread pool its rounds' frames."""
    from ..playback.renderer import BundleRenderer

    per_round = -(-max(30, int(frames)) // max(1, int(rounds)))
    players = [BundleRenderer(e.bundle) for e in entries]
    try:
        images = [[p.render(cameras, i) for i in range(len(cameras))] for p in players]
        times = [[] for _ in entries]
        for _ in range(max(1, int(rounds))):
            for k, p in enumerate(players):
                times[k].extend(p.time_frames(cameras, warmup=3, frames=per_round)["times_ms"])
        points = []
        for e, imgs, ms in zip(entries, images, times):
            timing = _spread_ms(np.asarray(ms) / 1000.0)
            points.append({"label": e.label, "kind": e.kind, "steps": None,
                           "seconds_per_frame": timing["median_ms"] / 1000.0, "timing": timing,
                           **scores(imgs, reference), **e.extra})
            if progress:
                progress()
        return points
    finally:
        for p in players:
            p.release()
