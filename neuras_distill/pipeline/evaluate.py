"""Evaluation: the field and the bundle on the same held-out cameras at the same resolution.

Times both sides on this machine ("before" = volume rendering the field, "after" = OpenGL playback of the
bundle), computes PSNR/SSIM of the bundle against the field, and the error-against-run-time points.

Fidelity beyond one PSNR (``fidelity``): FLIP per view, PSNR over the silhouette band and over the interior,
PSNR over the smooth region (where the field's own image is locally flat: mottling shows there), and the fraction
of pixels where the field is opaque but the bundle's mesh covers nothing (regions defined in ``metrics``: they come
from the field's own opacity and image of each view). For every view it also picks two crop
windows at native resolution: the silhouette-band and the interior area with the highest FLIP.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.ndimage import uniform_filter

from .. import metrics
from ..device import synchronize
from ..render.cameras import Cameras
from ..render.field_renders import FieldRenders

#: A held-out pixel counts as inside the foreground box when the field's opacity there (the box's, as seen through
#: what lies in front of it) is at least this; the rest is outside (the far region, or the background).
INSIDE_BOX_OPACITY = 0.5


def render_field_timed(renderer, cameras: Cameras, progress=None) -> tuple[list[np.ndarray], list[float]]:
    """Volume-render every camera; returns images (H,W,3) and seconds per frame."""
    renders = render_field_views(renderer, cameras, progress)
    return renders.images, renders.seconds


def render_field_views(renderer, cameras: Cameras, progress=None, *, depths: bool = False) -> FieldRenders:
    """Volume-render every camera (timed, one frame at a time); the surface and fringe depths only with
    ``depths`` (the teacher's views; timed held-out renders do not track them)."""
    renders = FieldRenders([], [], [], [], [])
    device = getattr(renderer, "device", None)
    if device is not None and device.type == "cuda" and len(cameras):
        renderer.render(cameras, 0, crossings=depths)   # warm-up on a GPU (kernels, allocator): not timed
    for i in range(len(cameras)):
        synchronize(device)
        t0 = time.perf_counter()
        out = renderer.render(cameras, i, crossings=depths)
        synchronize(device)
        renders.seconds.append(time.perf_counter() - t0)
        renders.images.append(out["rgb"])
        renders.opacities.append(out["opacity"])
        if depths:
            renders.surface_depths.append(out["surface_depth"])
            renders.fringe_depths.append(out["fringe_depth"])
        if progress is not None:
            progress(i + 1, len(cameras))
    return renders


def compare(bundle_images: list[np.ndarray], field_images: list[np.ndarray]) -> dict:
    """Per-view and mean PSNR/SSIM of bundle renders against the field's renders."""
    psnrs = [metrics.psnr(b, f) for b, f in zip(bundle_images, field_images)]
    ssims = [metrics.ssim(b, f) for b, f in zip(bundle_images, field_images)]
    return {"psnr": float(np.mean(psnrs)), "ssim": float(np.mean(ssims)),
            "psnr_per_view": psnrs, "ssim_per_view": ssims}


def error_vs_runtime(make_renderer, cameras: Cameras, reference_steps: int, step_counts: list[int],
                     main_steps: int, bundle_renderer,
                     main_render: tuple[np.ndarray, float] | None = None) -> list[dict]:
    """Points {label, seconds_per_frame, psnr} on camera 0 of ``cameras``: the field at each step count in
    ``step_counts`` and at ``main_steps``, and the bundle; all measured against the field at
    ``reference_steps`` (a denser march than any point). ``main_render``: the (H, W, 3) image of camera 0 at
    ``main_steps`` and its seconds, when the caller already rendered it that way (the held-out views: the same
    renderer, camera and resolution), used instead of rendering it again."""
    cam = cameras[0]
    reference = make_renderer(reference_steps).render(cam, 0)["rgb"]
    points = []
    for steps in sorted(set(step_counts) | {main_steps}):
        if steps == main_steps and main_render is not None:
            image, seconds = main_render
        else:
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
                    rasterize, skybox=None, world_cameras: Cameras | None = None,
                    silhouette_blend: bool = False) -> float:
    """PSNR of the OpenGL render of camera 0 against the torch forward pass of the same model on the same
    G-buffer: proves the baked bundle plays what was trained (8-bit framebuffer caps it near 59 dB).
    ``mesh`` and ``cameras`` in the bundle's frame; with a ``skybox`` the pixels the mesh misses are
    compared with its torch forward pass on the rays of ``world_cameras`` (camera 0). ``silhouette_blend``:
    the bundle plays with the soft-silhouette pass, so the reference gets its numpy mirror."""
    import torch

    from ..neural.model import view_inputs

    gbuffer = rasterize(mesh, cameras[0])
    dirs = view_inputs(cameras.rays(0)[1].numpy(), gbuffer.face_id[0], gbuffer.normal[0],
                       model.use_facing, mesh.core_faces if model.mesh_layers == 2 else None,
                       reflect=model.view_reflect)
    reference = model.render_gbuffer(gbuffer.uv[0], gbuffer.coverage[0], dirs, background)
    if skybox is not None:
        origins, world_dirs = world_cameras.rays(0)
        missed = ~gbuffer.coverage[0]
        with torch.no_grad():
            sky, _ = skybox(skybox.layers.relative(origins[torch.from_numpy(missed)]),
                            world_dirs[torch.from_numpy(missed)])
        reference[missed] = sky.numpy()
    if silhouette_blend:
        from ..playback.silhouette import blend_silhouettes, layer_coverage

        reference = blend_silhouettes(reference, layer_coverage(
            gbuffer.face_id[0], mesh.core_faces if model.mesh_layers == 2 else None))
    return metrics.psnr(gl_image, reference)


def bundle_coverage(rasterize, cameras: Cameras) -> list[np.ndarray]:
    """(H, W) bool per camera: where the bundle's mesh covers the pixel. ``rasterize(cameras) -> GBuffer`` is
    called one camera at a time (memory stays at one G-buffer)."""
    return [np.asarray(rasterize(cameras[i]).coverage[0], dtype=bool) for i in range(len(cameras))]


def worst_window(error_map: np.ndarray, region: np.ndarray, size: int = 256, box: int = 32,
                 min_share: float = 0.05) -> list[int] | None:
    """[x0, y0, w, h] of a ``size`` x ``size`` window (clamped into the (H, W) image; smaller images give the
    whole side) centred on the ``region`` pixel whose ``box`` x ``box`` neighbourhood has the highest mean
    error over its region pixels, among those whose neighbourhood is at least ``min_share`` region (all region
    pixels if none is). None for an empty region. ``error_map`` (H, W) float, ``region`` (H, W) bool."""
    err = np.asarray(error_map, dtype=np.float64)
    region = np.asarray(region, dtype=bool) & np.isfinite(err)
    if not region.any():
        return None
    h, w = err.shape
    k = max(1, min(box, h, w))
    den = uniform_filter(region.astype(np.float64), k, mode="constant")
    score = uniform_filter(np.where(region, err, 0.0), k, mode="constant") / np.maximum(den, 1e-12)
    ok = region & (den >= min_share)
    cy, cx = np.unravel_index(np.argmax(np.where(ok if ok.any() else region, score, -np.inf)), err.shape)
    cw, ch = min(size, w), min(size, h)
    x0 = int(np.clip(cx - cw // 2, 0, w - cw))
    y0 = int(np.clip(cy - ch // 2, 0, h - ch))
    return [x0, y0, cw, ch]


def view_fidelity(bundle_image: np.ndarray, field_image: np.ndarray, opacity: np.ndarray,
                  coverage: np.ndarray, band: int | None = None) -> tuple[dict, np.ndarray]:
    """Fidelity of one view: (H,W,3) bundle and field images, the field's (H,W) opacity (its foreground box's,
    as seen) and the bundle's (H,W) bool coverage. Returns ({"flip", "psnr_inside_box", "psnr_outside_box",
    "flip_inside_box", "flip_outside_box", "psnr_interior", "psnr_silhouette", "psnr_smooth", "smooth_fraction",
    "hole_fraction", "crops"},
    (H,W) float32 FLIP map): inside the box = pixels whose field opacity inside the foreground box is at least
    :data:`INSIDE_BOX_OPACITY`, outside = the rest (far ground, backdrop, sky or background). Region PSNRs are None
    for an empty region; "crops" holds the windows ``worst_window`` picks on the band ("a") and the interior ("b"),
    {"region", "box", "flip": the mean FLIP of the region's pixels in the window}; a view without pixels of a region
    has no crop for it."""
    mean_flip, flip_map = metrics.flip(bundle_image, field_image)
    band_mask = metrics.silhouette_band(opacity, band)
    interior = metrics.interior_mask(opacity, band_mask)
    crops = {}
    for key, name, region in (("a", "silhouette band", band_mask), ("b", "interior", interior)):
        box = worst_window(flip_map, region)
        if box is not None:
            x0, y0, cw, ch = box
            window = (slice(y0, y0 + ch), slice(x0, x0 + cw))
            crops[key] = {"region": name, "box": box, "flip": float(flip_map[window][region[window]].mean())}
    inside = np.asarray(opacity) >= INSIDE_BOX_OPACITY
    smooth = metrics.smooth_mask(field_image)
    return {"flip": mean_flip,
            "psnr_inside_box": metrics.region_psnr(bundle_image, field_image, inside),
            "psnr_outside_box": metrics.region_psnr(bundle_image, field_image, ~inside),
            "flip_inside_box": float(flip_map[inside].mean()) if inside.any() else None,
            "flip_outside_box": float(flip_map[~inside].mean()) if (~inside).any() else None,
            "psnr_interior": metrics.region_psnr(bundle_image, field_image, interior),
            "psnr_silhouette": metrics.region_psnr(bundle_image, field_image, band_mask),
            "psnr_smooth": metrics.region_psnr(bundle_image, field_image, smooth),
            "smooth_fraction": float(smooth.mean()),
            "hole_fraction": metrics.hole_fraction(opacity, coverage),
            "crops": crops}, flip_map


def _mean(values: list) -> float | None:
    """Mean of the values that are not None (NaN stays NaN); None when there are none."""
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def fidelity(bundle_images: list[np.ndarray], field_images: list[np.ndarray], opacities: list[np.ndarray],
             coverages: list[np.ndarray], band: int | None = None) -> tuple[dict, list[np.ndarray]]:
    """``view_fidelity`` of every view, and means over views (means of per-view values; region PSNRs over the
    views where the region is not empty). Returns (report entries: flip, psnr_interior, psnr_silhouette,
    psnr_smooth, smooth_fraction, hole_fraction, psnr_inside_box, psnr_outside_box, flip_inside_box,
    flip_outside_box, each with a ``_per_view`` list, silhouette_band_px, crops), [(H,W) float32 FLIP map]."""
    per_view, maps = [], []
    for b, f, op, cov in zip(bundle_images, field_images, opacities, coverages):
        entry, flip_map = view_fidelity(b, f, op, cov, band)
        per_view.append(entry)
        maps.append(flip_map)
    out: dict = {}
    for key in ("flip", "psnr_interior", "psnr_silhouette", "psnr_smooth", "smooth_fraction", "hole_fraction",
                "psnr_inside_box", "psnr_outside_box", "flip_inside_box", "flip_outside_box"):
        values = [v[key] for v in per_view]
        out[key] = _mean(values)
        out[f"{key}_per_view"] = values
    h, w = field_images[0].shape[:2] if field_images else (0, 0)
    out["silhouette_band_px"] = metrics.band_width(h, w) if band is None else int(band)
    out["crops"] = [v["crops"] for v in per_view]
    return out, maps


def _strip(panels: list[np.ndarray], gap: int = 4) -> np.ndarray:
    """(H, sum of widths + gaps, 3) uint8 of (H, w, 3) float panels in [0, 1], white gaps between them."""
    white = np.ones((panels[0].shape[0], gap, 3), np.float32)
    row = [panels[0]]
    for p in panels[1:]:
        row += [white, p]
    return (np.clip(np.concatenate(row, axis=1), 0, 1) * 255 + 0.5).astype(np.uint8)


def side_by_side(field_image: np.ndarray, bundle_image: np.ndarray, full_scale: float = 0.1,
                 flip_panel: np.ndarray | None = None) -> np.ndarray:
    """(H, 3W + 2*gap, 3) uint8: field | bundle | error heat map; with ``flip_panel`` (H, W, 3) float (the
    coloured FLIP map) a fourth panel: (H, 4W + 3*gap, 3)."""
    heat = metrics.error_heatmap(bundle_image, field_image, full_scale)
    return _strip([field_image, bundle_image, heat] + ([flip_panel] if flip_panel is not None else []))


def crop_strip(field_image: np.ndarray, bundle_image: np.ndarray, flip_panel: np.ndarray,
               box: list[int]) -> np.ndarray:
    """(h, 3w + 2*gap, 3) uint8: field | bundle | FLIP panel cut to ``box`` [x0, y0, w, h], no scaling."""
    x0, y0, w, h = box
    return _strip([np.asarray(p)[y0:y0 + h, x0:x0 + w] for p in (field_image, bundle_image, flip_panel)])


def plain_texture_baseline(model, bundle, train_gbuffer, train_inputs, test: Cameras, field_images: list,
                           bundle_images: list, coverages: list, fps_frames: int) -> dict:
    """What the neural shader buys: the model's plain RGB texture (``bake.plain_texture``) played in the same GL
    pipeline on the held-out cameras (the neural bundle's pixels where the mesh covers nothing, so a skybox
    counts alike), scored against the field like the bundle. Returns the report's ``plain_texture`` entry.
    The texture is the bundle's stored one (``bundle.plain_rgb``, 8-bit, gutters padded: what the glTF export
    carries) when it has one, else computed here from ``model`` and the training G-buffer."""
    from ..bake.plain_texture import plain_bundle, plain_texture
    from ..flip_metric import flip
    from ..playback.renderer import BundleRenderer

    if getattr(bundle, "plain_rgb", None) is not None:
        rgb = bundle.plain_rgb.astype(np.float32) / np.float32(255.0)
    else:
        rgb = plain_texture(model, train_gbuffer.uv, train_gbuffer.coverage, train_inputs)
    with BundleRenderer(plain_bundle(bundle, rgb)) as player:
        images = [np.where(cov[..., None], player.render(test, i, skybox=False), full)
                  for i, (cov, full) in enumerate(zip(coverages, bundle_images))]
        timing = player.time_frames(test, warmup=3, frames=fps_frames)
    quality = compare(images, field_images)
    flips = [flip(img, ref)[0] for img, ref in zip(images, field_images)]
    return {"psnr": quality["psnr"], "ssim": quality["ssim"], "flip": float(np.mean(flips)),
            "psnr_per_view": quality["psnr_per_view"], "frame_time_ms": timing["median_ms"],
            "texture": [int(rgb.shape[0]), int(rgb.shape[1])],
            "how": "the neural shader evaluated once per texel at the mean view input its training pixels had, "
                   "stored in 8 bits (the bundle's plain_rgb.png, the glTF export's base colour), played "
                   "bilinearly in the same GL pipeline (mesh, draw calls, cameras)"}
