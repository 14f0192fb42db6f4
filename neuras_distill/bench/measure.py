"""The bench's points: error against the field and time per frame, on the run's held-out cameras.

Every point at a resolution is scored against the same reference: the field marched with twice the steps of
its densest point (``reference_steps``), on every held-out view. Errors are means over the views of PSNR, SSIM
(``metrics``) and FLIP (``flip_metric``, 0 = identical).

Timing: the field (torch, this machine's CPU or GPU) renders each view once after one warm-up frame; its point
is the median over the views, with the 10th-90th percentile spread. GL frames (bundles and the plain-texture
floor) are timed by ``BundleRenderer.time_frames`` (``ctx.finish()`` before each clock stop), 5 warm-up frames
then ``frames`` (>= 30) cycling through the views: median and 10th-90th percentiles.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .. import metrics
from ..flip_metric import flip


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


def render_reference(field, cameras, steps: int, progress=None) -> Reference:
    """The field at ``steps`` per box diagonal on every camera (not timed)."""
    from ..render.volume import VolumeRenderer

    renderer = VolumeRenderer(field, num_steps=int(steps))
    images = []
    for i in range(len(cameras)):
        images.append(renderer.render(cameras, i)["rgb"])
        if progress:
            progress()
    return Reference(int(steps), images)


def field_point(field, cameras, steps: int, reference: Reference, progress=None) -> dict:
    """The field marched with ``steps``: scored and timed on every camera (one warm-up frame first)."""
    from ..render.volume import VolumeRenderer

    renderer = VolumeRenderer(field, num_steps=int(steps))
    renderer.render(cameras, 0)
    images, seconds = [], []
    for i in range(len(cameras)):
        t0 = time.perf_counter()
        images.append(renderer.render(cameras, i)["rgb"])
        seconds.append(time.perf_counter() - t0)
        if progress:
            progress()
    timing = _spread_ms(seconds)
    return {"label": f"field, {steps} steps", "kind": "field", "steps": int(steps),
            "seconds_per_frame": timing["median_ms"] / 1000.0, "timing": timing, **scores(images, reference)}


def gl_point(bundle, cameras, reference: Reference, *, label: str, kind: str, frames: int = 30) -> dict:
    """A bundle (or the plain-texture bundle) played by ``BundleRenderer``: scored on every camera, timed."""
    from ..playback.renderer import BundleRenderer

    with BundleRenderer(bundle) as player:
        images = [player.render(cameras, i) for i in range(len(cameras))]
        timing = player.time_frames(cameras, warmup=5, frames=max(30, int(frames)))
    spread = {k: timing[k] for k in ("median_ms", "p10_ms", "p90_ms", "frames")}
    return {"label": label, "kind": kind, "steps": None, "seconds_per_frame": timing["median_ms"] / 1000.0,
            "timing": spread, **scores(images, reference)}
