"""Evaluation: the field and the bundle on the same held-out cameras at the same resolution.

Times both sides on this machine ("before" = volume rendering the field, "after" = OpenGL playback of the
bundle), computes PSNR/SSIM of the bundle against the field, and the error-against-run-time points.
"""

from __future__ import annotations

import time

import numpy as np

from .. import metrics
from ..render.cameras import Cameras


def render_field_timed(renderer, cameras: Cameras, progress=None) -> tuple[list[np.ndarray], list[float]]:
    """Volume-render every camera; returns images (H,W,3) and seconds per frame."""
    images, seconds = [], []
    for i in range(len(cameras)):
        t0 = time.perf_counter()
        images.append(renderer.render(cameras, i)["rgb"])
        seconds.append(time.perf_counter() - t0)
        if progress is not None:
            progress(i + 1, len(cameras))
    return images, seconds


def compare(bundle_images: list[np.ndarray], field_images: list[np.ndarray]) -> dict:
    """Per-view and mean PSNR/SSIM of bundle renders against the field's renders."""
    psnrs = [metrics.psnr(b, f) for b, f in zip(bundle_images, field_images)]
    ssims = [metrics.ssim(b, f) for b, f in zip(bundle_images, field_images)]
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)),
            "psnr_per_view": psnrs, "ssim_per_view": ssims}


def error_vs_runtime(make_renderer, cameras: Cameras, reference_steps: int, step_counts: list[int],
                     main_steps: int, bundle_renderer, main_seconds: float | None = None) -> list[dict]:
    """Points {label, seconds_per_frame, psnr} on camera 0 of ``cameras``: the field at each step count in
    ``step_counts`` and at ``main_steps``, and the bundle; all measured against the field at
    ``reference_steps`` (a denser march than any point)."""
    cam = cameras[0]
    reference = make_renderer(reference_steps).render(cam, 0)["rgb"]
    points = []
    for steps in sorted(set(step_counts) | {main_steps}):
        renderer = make_renderer(steps)
        t0 = time.perf_counter()
        image = renderer.render(cam, 0)["rgb"]
        seconds = time.perf_counter() - t0
        points.append({"label": f"field, {steps} steps/ray", "kind": "field", "steps": steps,
                       "seconds_per_frame": seconds, "psnr": metrics.psnr(image, reference)})
    timing = bundle_renderer.time_frames(cam, warmup=3, frames=10)
    image = bundle_renderer.render(cam, 0)
    points.append({"label": "bundle (OpenGL)", "kind": "bundle", "steps": None,
                   "seconds_per_frame": timing["median_ms"] / 1000.0, "psnr": metrics.psnr(image, reference)})
    return points


def gl_torch_parity(model, mesh, cameras: Cameras, gl_image: np.ndarray, background: np.ndarray,
                    rasterize, skybox=None, world_cameras: Cameras | None = None) -> float:
    """PSNR of the OpenGL render of camera 0 against the torch forward pass of the same model on the same
    G-buffer: proves the baked bundle plays what was trained (8-bit framebuffer caps it near 59 dB).
    ``mesh`` and ``cameras`` in the bundle's frame; with a ``skybox`` the pixels the mesh misses are
    compared with its torch forward pass on the rays of ``world_cameras`` (camera 0)."""
    import torch

    gbuffer = rasterize(mesh, cameras[0])
    dirs = cameras.rays(0)[1].numpy()
    reference = model.render_gbuffer(gbuffer.uv[0], gbuffer.coverage[0], dirs, background)
    if skybox is not None:
        origins, world_dirs = world_cameras.rays(0)
        missed = ~gbuffer.coverage[0]
        with torch.no_grad():
            sky, _ = skybox(skybox.layers.relative(origins[torch.from_numpy(missed)]),
                            world_dirs[torch.from_numpy(missed)])
        reference[missed] = sky.numpy()
    return metrics.psnr(gl_image, reference)


def side_by_side(field_image: np.ndarray, bundle_image: np.ndarray, full_scale: float = 0.1) -> np.ndarray:
    """(H, 3W + 2*gap, 3) uint8: field | bundle | error heat map."""
    heat = metrics.error_heatmap(bundle_image, field_image, full_scale)
    h = field_image.shape[0]
    gap = np.ones((h, 4, 3), np.float32)
    row = np.concatenate([field_image, gap, bundle_image, gap, heat], axis=1)
    return (np.clip(row, 0, 1) * 255 + 0.5).astype(np.uint8)
