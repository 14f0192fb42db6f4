"""The measurements, thresholds and numeric rules that ``choices.py`` applies (it holds the ``Decision`` records):
what a scene does not need, how large its atlas is, how long it trains.

* view direction: the field's colour at surface points is compared across view directions; when it barely
  changes, the MLP shader gets no view input (and the generated GLSL has none).
* skyboxes: a field whose background is one constant colour (or that has no background) needs none.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy import ndimage

from ..config import TextureConfig, TrainConfig
from ..geometry.mesh import MeshData

if TYPE_CHECKING:
    from ..fields.base import Field


def measure_view_dependence(field: Field, mesh: MeshData, *, num_points: int = 2048, num_dirs: int = 8,
                            seed: int = 0) -> float:
    """Mean over surface points and channels of the standard deviation of colour (0..1) across ``num_dirs``
    random view directions that reach the point from outside (the hemisphere around the face normal)."""
    rng = np.random.default_rng(seed)
    v, f = mesh.vertices.astype(np.float64), mesh.faces
    if len(f) == 0:
        return 0.0
    pick = rng.choice(len(f), size=min(num_points, len(f)), replace=False)
    tri = v[f[pick]]
    bary = rng.dirichlet(np.ones(3), size=len(pick))
    points = np.einsum("nk,nkc->nc", bary, tri)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    dirs = rng.normal(size=(len(pick), num_dirs, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    # Directions of travel point into the surface: d . n < 0.
    flip = np.einsum("ndc,nc->nd", dirs, normals) > 0
    dirs[flip] *= -1
    x = torch.as_tensor(np.repeat(points, num_dirs, axis=0), dtype=torch.float32)
    d = torch.as_tensor(dirs.reshape(-1, 3), dtype=torch.float32)
    with torch.no_grad():
        rgb = field.radiance(x, d).reshape(len(pick), num_dirs, 3).double()
    return float(rgb.std(dim=1).mean())


#: Margin around the field's foreground box, as a fraction of its diagonal, inside which a training pixel's
#: visible surface counts as foreground (``near_miss_pixels``).
NEAR_MISS_BOX_MARGIN = 0.01
#: How far from the mesh's silhouette, as a fraction of the training view's width, a pixel where the field only
#: reaches its fringe opacity still counts as a near miss (``near_miss_pixels``). The street's tree-crown edges lie
#: within 8 pixels of the mesh at 480 wide (99.8% of them; at 1%, 4.8 pixels, the few beyond trained a smudge back
#: into a held-out view's sky); a nerfacto run's haze fills a 360° capture's box far from any surface (the median
#: such pixel lies 19 pixels from the mesh at 160 wide) and shows the sky behind it.
NEAR_MISS_FRINGE_REACH = 0.02
#: A near miss by its fringe alone (the field under 0.5 opacity inside the box) whose whole ray reaches 0.5
#: beyond the box shows mostly what lies behind: the ground or a building the skyboxes hold, seen past the edge
#: of the box's floor or through the haze at an object's rim. Such pixels are given back to the skyboxes
#: (``choices.sky_training_pixels``), probed on at most ``SEE_THROUGH_PROBE_RAYS`` of them with
#: ``SEE_THROUGH_PROBE_STEPS`` samples each (the rest stay near misses). On checker360 they were a fifth of the
#: floor beyond the mesh in the training views, and a skybox that never learnt them drew them at 17 dB.
SEE_THROUGH_PROBE_RAYS = 65536
SEE_THROUGH_PROBE_STEPS = 128


#: Skybox layer counts (``skybox.layers`` 0): the usual one, and the finer one for skyboxes that hold ground.
SKY_LAYERS = (4, 8)
#: Share of the pixels the skyboxes learn that look below the horizon (more than 2 degrees under the training
#: cameras' mean up) from which they get ``SKY_LAYERS[1]`` layers: ground beyond the mesh, whose distance changes
#: across the view, where a sky's does not. Measured with fixed steps on the stored stages: checker360 (30% below)
#: 23.36 -> 24.41 dB with 8 layers (12: 24.57, 16: 24.65), orbit360 (51%) 27.19 -> 27.68; the street (9%) 32.67
#: -> 32.67 dB at 6000 steps for 17% more frame time (32.0 -> 37.6 ms at 960x540 on llvmpipe).
SKY_GROUND_SHARE = 0.2
#: The skyboxes' codebook when ``skybox.num_codes`` is 0: (for a sky, for skyboxes that hold ground). On
#: checker360 (README CPU command) the sky above the horizon played at 34.0 dB against nerfstudio's renders with
#: the skyboxes' continuous features and 30.5 with 4096 codes; 16384 took the frame 27.83 -> 28.44 dB for 18 s
#: more k-means and 0.4 MB more bundle. 16384 is the most a sky codebook plays natively (it is never wrapped).
SKY_CODES = (4096, 16384)
SKY_HORIZON_DEG = 2.0


def below_horizon_share(directions, pixels, up) -> float:
    """Share of ``pixels`` ((N, H, W) bool) whose ray ``directions`` ((N, H, W, 3) world, unit; read view by view,
    so a memory-mapped array stays on disk) point more than :data:`SKY_HORIZON_DEG` below ``up`` ((3,))."""
    up = np.asarray(up, np.float64)
    up = up / max(float(np.linalg.norm(up)), 1e-30)
    limit = -np.sin(np.radians(SKY_HORIZON_DEG))
    below = total = 0
    for i in range(len(pixels)):
        chosen = np.asarray(directions[i])[np.asarray(pixels[i])]
        below += int(np.count_nonzero(chosen @ up < limit))
        total += len(chosen)
    return below / total if total else 0.0


#: Skyboxes that hold ground (``SKY_GROUND_SHARE``) lie on it (``neural.skybox.SkyboxGround``) where their rays
#: that look below the horizon reach opacity 0.5 in the field before its far plane, probed on at most
#: ``GROUND_PROBE_RAYS`` of them with ``GROUND_PROBE_STEPS`` samples each; a layer's floor is the median height of
#: the hits in its ring when it holds at least ``GROUND_MIN_HITS`` of them. No share of hits is asked for: on
#: orbit360 only 43% of the probed rays reach 0.5 (a faint, partly trained far ground), and floors at the heights
#: of those that do scored 27.68 -> 29.28 dB against the teacher (checker360, 100% reach it: 24.41 -> 25.28).
#: More rays with more hits a ring (16,384 and 32) made orbit360's near floors worse, not steadier
#: (docs/decisions.md, "Skyboxes that hold ground lie on it").
GROUND_PROBE_RAYS = 4096
GROUND_PROBE_STEPS = 256
GROUND_MIN_HITS = 16


def ground_heights(hits: np.ndarray, up: np.ndarray, half_sizes: np.ndarray,
                   camera_heights: np.ndarray) -> tuple[np.ndarray, dict]:
    """Each skybox layer's floor from where rays that look down reach the field's ground.

    Layer ``l``'s floor holds what lies between the cube ``l - 1`` and the cube ``l`` around the centre, seen
    from above: its ring is ``r_{l-1} <= max(|p_i|, |p_j|) < r_l`` over the two cube axes other than the one
    closest to ``up`` (``r_{-1} = 0``). Its height is the median height of the hits in that ring; a ring with
    fewer than :data:`GROUND_MIN_HITS` takes the nearest ring's that has them (the inner one on a tie). Every
    floor is kept 1% of the innermost layer below the lowest camera.

    Args:
        hits: (M, 3) float64 points where probed rays reach opacity 0.5, relative to the layers' centre.
        up: (3,) unit up direction. half_sizes: (L,) the layers' half sizes.
        camera_heights: (N,) the cameras' heights along ``up``, relative to the centre.
    Returns:
        ((L,) float64 heights along ``up`` relative to the centre, {"hits_per_layer": [...]}); the heights are
        empty when no ring holds enough hits.
    """
    hits, up = np.asarray(hits, np.float64).reshape(-1, 3), np.asarray(up, np.float64)
    r = np.asarray(half_sizes, np.float64)
    axis = int(np.argmax(np.abs(up)))
    across = [k for k in range(3) if k != axis]
    reach = np.abs(hits[:, across]).max(axis=1) if len(hits) else np.zeros(0)
    height = hits @ up
    inner = np.concatenate([[0.0], r[:-1]])
    counts = [int(np.count_nonzero((reach >= a) & (reach < b))) for a, b in zip(inner, r)]
    filled = [i for i, c in enumerate(counts) if c >= GROUND_MIN_HITS]
    if not filled:
        return np.zeros(0), {"hits_per_layer": counts}
    out = np.empty(r.size)
    for layer in range(r.size):
        src = min(filled, key=lambda i: (abs(i - layer), i))
        a, b = inner[src], r[src]
        out[layer] = float(np.median(height[(reach >= a) & (reach < b)]))
    ceiling = float(np.min(camera_heights)) - 0.01 * float(r[0])
    return np.minimum(out, ceiling), {"hits_per_layer": counts}


#: A skybox pixel whose ray holds at least this opacity inside the foreground box shows content the mesh missed
#: there (``choices.sky_training_pixels`` reports their share; below 0.5 they are not near misses, so the skyboxes
#: still learn them).
SKY_INSIDE_BOX_OPACITY = 0.2


def near_miss_pixels(surface_depths: np.ndarray, fringe_depths: np.ndarray, coverage: np.ndarray,
                     origins: np.ndarray, dirs: np.ndarray, aabb, margin: float = NEAR_MISS_BOX_MARGIN,
                     fringe_reach: float = NEAR_MISS_FRINGE_REACH) -> np.ndarray:
    """(N, H, W) bool: training pixels the mesh misses although the field shows a surface inside its foreground
    box there (a lamp arm thinner than a voxel, the soft edge of a tree). Trained into the skyboxes, such pixels
    paint foreground colours into the sky, where every other view sees them as smudges; they are left out of the
    skyboxes' training instead.

    A pixel counts when the field's opacity reaches 0.5 inside the box (``surface_depths``), or when it reaches
    the fringe level (``fringe_depths``, ``render.volume.FRINGE_OPACITY``) inside the box within
    ``fringe_reach`` · W pixels of a pixel the mesh covers: the half-transparent edge of a part the mesh does hold
    (on the street, tree-crown edges trained the innermost skybox to 0.54 opacity and painted a green disc into
    a held-out view's sky). Fringe-level pixels far from the mesh are haze the sky shows through, and stay in.

    Args:
        surface_depths, fringe_depths: (N, H, W) float32 ray distances where the field's opacity reaches 0.5 and
            the fringe level (0: never).
        coverage: (N, H, W) bool, pixels the mesh covers.
        origins: (N, 3) camera centres, dirs: (N, H, W, 3) unit ray directions, both in the field's world frame.
        aabb: the field's foreground box, (2, 3) or (6,) min and max corners (world frame).
        margin: box growth as a fraction of its diagonal.
        fringe_reach: the fringe level's reach from the mesh's silhouette, as a fraction of the view's width.
    """
    box = np.asarray(torch.as_tensor(aabb).double().reshape(2, 3).cpu().numpy())
    grow = margin * float(np.linalg.norm(box[1] - box[0]))
    lo, hi = box[0] - grow, box[1] + grow
    reach = fringe_reach * coverage.shape[2]
    out = np.zeros(coverage.shape, dtype=bool)
    for i in range(coverage.shape[0]):
        depth = surface_depths[i].astype(np.float64)
        if coverage[i].any():
            near_mesh = ndimage.distance_transform_edt(~coverage[i]) <= reach
            depth = np.where((depth <= 0) & near_mesh, fringe_depths[i].astype(np.float64), depth)
        candidates = ~coverage[i] & (depth > 0)
        if not candidates.any():
            continue
        hit = (np.asarray(origins[i], dtype=np.float64)
               + np.asarray(dirs[i][candidates], dtype=np.float64) * depth[candidates, None])
        out[i][candidates] = np.all((hit >= lo) & (hit <= hi), axis=1)
    return out


def background_is_constant(field) -> tuple[bool, str]:
    """(True, description) when every ray that misses the foreground sees one constant colour."""
    if getattr(field, "unbounded", False):
        return False, "the field is unbounded: content lies outside its box"
    if callable(getattr(field, "background", None)):
        dirs = torch.nn.functional.normalize(torch.randn(512, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
        with torch.no_grad():
            bg = field.background(dirs).double()
        spread = float((bg - bg.mean(0)).abs().max())
        if spread > 1.0 / 255.0:
            return False, f"the background changes with direction (max deviation {spread:.3f})"
        colour = bg.mean(0).tolist()
    else:
        colour = background_color(field).tolist()
    return True, "every ray that misses the foreground sees one constant colour " + \
        "(" + ", ".join(f"{c:.3f}" for c in colour) + "); it is the clear colour"


def background_color(field) -> torch.Tensor:
    """(3,) float32 constant background colour of a field (black when it has none)."""
    bg = getattr(field, "background_color", None)
    if bg is None:
        return torch.zeros(3)
    return torch.as_tensor(bg, dtype=torch.float32).reshape(3)


#: Pixels along one texel side, in the training view that sees the texel largest. Rays sample the atlas at
#: pixel centres, so a texel needs about 2 x 2 samples in a view (Nyquist) to be fitted consistently across
#: views. Measured (held-out PSNR, 3000 steps, 400^2 views): NeuS fixture 32.0 dB at 256^2 vs 31.3 at 512^2;
#: instant-nsr-pl fixture 29.4 / 28.9 / 28.2 / 26.6 dB at 256^2 / 384^2 / 512^2 / 1024^2.
PIXELS_PER_TEXEL = 2.0

#: The teacher and the held-out frames render at most this many times the cameras' own width: a dataset of
#: 128-pixel images (the nerfstudio fixture) is not rendered at 640 / 1920 pixels, where the field has no detail
#: its training images showed and the plain-PyTorch fields take minutes per frame. Generated cameras are 1920
#: wide, so the default sizes (640 teacher, 1920 held out) are unchanged for them.
MAX_UPSCALE = 2.0


def capped_width(width: int, native_width: int, max_upscale: float = MAX_UPSCALE) -> int:
    """The render width for a configured ``width`` and cameras ``native_width`` wide, at most ``max_upscale``
    times their width (0: no cap)."""
    if not max_upscale:
        return int(width)
    return min(int(width), int(round(max_upscale * native_width)))


def texel_density_resolution(mesh: MeshData, cameras, *, pixels_per_texel: float = PIXELS_PER_TEXEL,
                             multiple: int = 64, lo: int = 128, hi: int = 4096) -> tuple[int, dict]:
    """Atlas side giving texels of about ``pixels_per_texel`` x ``pixels_per_texel`` training pixels.

    For every face the footprint in pixels is taken from the camera that sees it largest (pinhole projection of
    a small patch: area x cos(viewing angle) x fx fy x distance / depth^3, for cameras it faces with its
    centroid inside the frame;
    occlusion is ignored, so hidden faces count as seen: a slight overestimate). With ``A_px`` the sum of
    those footprints and ``A_uv`` the faces' total uv area (fraction of the unit square),
    ``R = sqrt(A_px / A_uv) / pixels_per_texel``, rounded up to a multiple of ``multiple`` and clamped to [lo, hi].

    Args:
        mesh: vertices (V, 3) world, faces (F, 3), uvs (V, 2) in [0, 1].
        cameras: ``Cameras`` (the training views, at the training resolution).
    Returns:
        (R, {"pixels": A_px, "uv_area": A_uv, "exact": unrounded R}).
    """
    best, _ = face_footprints(mesh, cameras)
    pixels, uv_total = float(best.sum()), mesh.uv_area()
    exact = (float(np.sqrt(pixels / uv_total)) / float(pixels_per_texel)
             if uv_total > 0 and pixels > 0 else float(lo))
    r = int(min(hi, max(lo, multiple * np.ceil(exact / multiple))))
    return r, {"pixels": pixels, "uv_area": uv_total, "exact": exact}


def face_footprints(mesh: MeshData, cameras) -> tuple[np.ndarray, np.ndarray]:
    """(F,) pixels each face covers in the training view that sees it largest (the pinhole footprint of
    :func:`texel_density_resolution`; occlusion ignored) and (F,) the faces' areas in world units²."""
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces
    tri = v[f]
    centroid = tri.mean(axis=1)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2.0 * area[:, None], 1e-30)
    best = np.zeros(len(f))
    for i in range(len(cameras)):
        c2w = cameras.c2w[i].double().numpy()
        rel = centroid - c2w[:3, 3]
        cam = rel @ c2w[:3, :3]                       # camera frame: x right, y up, -z forward
        depth = -cam[:, 2]
        dist = np.linalg.norm(rel, axis=1)
        facing = -np.einsum("ij,ij->i", normal, rel) / np.maximum(dist, 1e-30)
        fx, fy = float(cameras.fx[i]), float(cameras.fy[i])
        px = fx * cam[:, 0] / np.maximum(depth, 1e-30) + float(cameras.cx[i])
        py = -fy * cam[:, 1] / np.maximum(depth, 1e-30) + float(cameras.cy[i])
        ok = (depth > 0) & (facing > 0) & (px >= 0) & (px < cameras.width) & (py >= 0) & (py < cameras.height)
        # pinhole footprint of a small patch: area * cos * f^2 * distance / depth^3
        foot = np.where(ok, area * facing * fx * fy * dist / np.maximum(depth, 1e-30) ** 3, 0.0)
        np.maximum(best, foot, out=best)
    return best, area


def view_texel_weights(mesh: MeshData, cameras) -> np.ndarray:
    """(F,) texel density each face wants: training pixels per unit area in the view that sees it largest
    (:func:`face_footprints`); faces no training view frames (kept by the conservative culling) get the 5th
    percentile of the others. For ``geometry.unwrap.unwrap(face_weights=...)``."""
    pixels, area = face_footprints(mesh, cameras)
    density = pixels / np.maximum(area, 1e-30)
    seen = density > 0
    floor = float(np.percentile(density[seen], 5)) if seen.any() else 1.0
    return np.maximum(density, max(floor, 1e-12))


#: Training samples (pixels drawn over the whole run) each used texel should get at least. With fewer the
#: atlas is under-trained: on the instant-nsr-pl fixture at 3000 steps a 512^2 atlas (~185 samples per used
#: texel) scored 1.1 dB below a 256^2 one (~670), and 1500 steps scored 1.2 dB below 3000 at 512^2.
SAMPLES_PER_TEXEL = 256


#: The final unwrap at the chosen side must give at least this share of the texels the texel-density rule asked
#: for. Many small charts (a noisy NeRF surface: 1329 charts for 35k faces on the nerfstudio fixture) each keep
#: their padding in texels, so at a small side the padding takes most of the atlas (10% of a 256² atlas held
#: surface there, where the trial at 1024 had 50%: 12.6 training pixels per texel instead of 4).
MIN_TEXEL_YIELD = 0.6


def side_for_texels(side: int, used_texels: float, wanted_texels: float, *, hi: int, multiple: int = 64) -> int:
    """A larger atlas side when ``side`` gives fewer than :data:`MIN_TEXEL_YIELD` of ``wanted_texels`` used
    texels (scaled by the square root of the shortfall, a multiple of ``multiple``, at most ``hi``); else
    ``side``."""
    if used_texels >= MIN_TEXEL_YIELD * wanted_texels or side >= hi:
        return int(side)
    grown = side * float(np.sqrt(wanted_texels / max(used_texels, 1.0)))
    return int(min(hi, multiple * np.ceil(grown / multiple)))


def training_budget_resolution(samples: int, uv_area: float, *, per_texel: int = SAMPLES_PER_TEXEL,
                               multiple: int = 64, lo: int = 128) -> int:
    """Largest atlas side whose used texels (``uv_area`` of the atlas) each get ``per_texel`` of the run's
    ``samples`` training pixels, rounded up to ``multiple``, at least ``lo``."""
    exact = float(np.sqrt(max(samples, 1) / (per_texel * max(uv_area, 1e-9))))
    return int(max(lo, multiple * np.ceil(exact / multiple)))


#: Fewest optimisation steps of an automatic plan (the MLP needs some steps whatever the atlas size).
MIN_TRAIN_STEPS = 1000
#: Training samples per used texel an automatic plan aims for (the texel rule; ``SAMPLES_PER_TEXEL`` is the
#: least the atlas size allows). More kept paying off: on the instant-nsr-pl fixture at 384^2,
#: 1500 / 3000 / 5000 steps (about 330 / 660 / 1100 samples per used texel) gave ~29 / 30.1 / 30.7 dB.
#: 2048, not 1024 (with exact codes for small atlases, same stored stages, held out): demo 38.33 ->
#: 38.83 dB, from-ngp ball 39.33 -> 39.54 (interior 37.04 -> 37.47), NeuS 37.63 -> 38.00, instant-nsr-pl
#: 34.10 -> 34.42.
TARGET_SAMPLES_PER_TEXEL = 2048

#: The most seconds an automatic plan trains when neither ``train.time_budget_s`` nor ``--time-budget`` says
#: otherwise: a safety net, not the rule. Training stops before it at the texel rule
#: (:data:`TARGET_SAMPLES_PER_TEXEL`) or on a plateau of the held-back pixels (``neural.convergence``). Before,
#: training's budget was the time the run spent volume rendering, so a faster GPU trained less: on an H200 the
#: street ran 18,937 of the 36,049 steps its texel rule asks for in 76 s.
TRAIN_CAP_S = 600.0
#: The plateau rule (``neural.convergence.PlateauStop``): one training pixel in HOLD_BACK_EVERY is held back;
#: they are scored every ``steps // PLATEAU_CHECKS`` steps, and training stops once past PLATEAU_MIN_PROGRESS of
#: its steps when the best of the last PLATEAU_PATIENCE scores is less than PLATEAU_MIN_GAIN_DB above the best
#: before them.
HOLD_BACK_EVERY = 64
PLATEAU_CHECKS = 40
PLATEAU_PATIENCE = 4
PLATEAU_MIN_GAIN_DB = 0.05
PLATEAU_MIN_PROGRESS = 0.5


def run_budget_left(budget_s: float, elapsed_s: float, eval_seconds: float) -> float:
    """Seconds a run budget of ``budget_s`` leaves training after ``elapsed_s`` spent and ``eval_seconds`` kept
    for the evaluation; BadInputError (naming a budget that would do) when nothing is left."""
    from ..errors import require

    left = budget_s - elapsed_s - eval_seconds
    require(left > 0, f"--time-budget {budget_s:g}: the stages before training took {elapsed_s:.0f} s and the "
                      f"evaluation needs about {eval_seconds:.0f} s, which leaves no time to train; pass "
                      f"--time-budget {1.5 * (elapsed_s + eval_seconds) + 60:.0f} or more")
    return float(left)


def training_cap_s(time_budget_s, run_budget_s, elapsed_s: float, eval_seconds: float):
    """Training's time cap in seconds, or None for none: ``time_budget_s`` (``train.time_budget_s``; 0 or None:
    none), or less when a run budget (``train.run_budget_s``, ``--time-budget``) leaves less after ``elapsed_s``
    spent and ``eval_seconds`` kept for the evaluation (:func:`run_budget_left`). The plan takes it after the
    teacher, training again when it starts."""
    cap = time_budget_s or None
    if run_budget_s:
        left = run_budget_left(run_budget_s, elapsed_s, eval_seconds)
        cap = min(cap or left, left)
    return cap


def evaluation_seconds(teacher_seconds: float, teacher_pixels: int, eval_pixels: int) -> float:
    """The held-out evaluation's volume rendering in seconds, estimated from the teacher's seconds per pixel
    (``eval_pixels`` counts every field pixel the evaluation renders)."""
    return float(teacher_seconds) / max(teacher_pixels, 1) * eval_pixels


def probe_training_speed(texture: TextureConfig, train: TrainConfig, steps: int = 60, side: int = 256,
                         device: torch.device | str | None = None) -> float:
    """Optimisation steps per second of ``neural.train.fit`` on ``device`` (default the CPU) for this model size,
    measured on a small synthetic problem (random uvs; a step's cost does not depend on the data) after 20
    warm-up steps (on an H100 the demo's model trains at 267 steps/s where its 16 CPU cores probe 106).
    Continuous features (quantization happens after training and costs no steps); no skybox (scenes with
    skyboxes train a little slower than probed). The fastest of :data:`PROBE_SEGMENTS` timed segments counts."""
    from ..neural.model import NeuralTextureModel
    from ..neural.train import fit
    from ..neural.train_batches import TrainingPixels

    gen = torch.Generator().manual_seed(0)
    n, h, w = 2, 4 * train.patch, 4 * train.patch
    model = NeuralTextureModel(side, side, feature_dim=texture.feature_dim, hidden=texture.hidden,
                               num_layers=texture.num_layers, output_layers=texture.output_layers, use_vq=False,
                               coarse_factor=texture.coarse_factor)
    uv = torch.rand(n, h, w, 2, generator=gen)
    dirs = torch.nn.functional.normalize(torch.randn(n, h, w, 3, generator=gen), dim=-1)
    data = (uv, torch.ones(n, h, w, dtype=torch.bool), dirs, torch.rand(n, h, w, 3, generator=gen))
    config = TrainConfig(batch_patches=train.batch_patches, patch=train.patch)   # the batch's size, nothing else
    fit(model, TrainingPixels(*data), steps=20, config=config, progress=False, device=device)
    rates = [fit(model, TrainingPixels(*data), steps=max(1, steps // PROBE_SEGMENTS), config=config,
                 progress=False, device=device).steps_per_second for _ in range(PROBE_SEGMENTS)]
    return float(max(rates))


#: The training-speed probe's steps are timed in this many segments and the fastest counts: a moment of
#: contention on a shared machine slows one segment, not the plan (the demo's probe once read 46 steps/s where
#: it reads 83-85, and the plan cut its training from 3505 to 2753 steps: 38.33 -> 37.61 dB). An optimistic
#: figure costs nothing: training still stops at its time budget.
PROBE_SEGMENTS = 3


def training_steps(used_texels: float, samples_per_step: int, affordable_steps: int,
                   per_texel: int = TARGET_SAMPLES_PER_TEXEL, min_steps: int = MIN_TRAIN_STEPS) -> tuple[int, int]:
    """(steps, needed): the steps that give every used texel ``per_texel`` training samples (``needed``),
    limited to ``affordable_steps`` and at least ``min_steps``."""
    needed = int(np.ceil(used_texels * per_texel / max(samples_per_step, 1)))
    return int(max(min_steps, min(needed, affordable_steps))), needed


#: Fringe width (training-view pixels) from which the mesh encloses the field's soft fringe. Measured with the
#: same inputs and 1500 steps: the gradient ball (fringe 13 px at 640 wide) went from 29.9 to 34.8 dB
#: held-out (silhouette band 17.0 -> 25.0 dB); the demo bunny (fringe 1.5 px) went from 33.9 to 30.6 dB: half
#: a voxel of offset showed surface colour where the field shows background. The NeuS fixture (a fringe
#: of 3.1 px at 400 wide) scored 31.6 dB with the shell and 33.1 dB without.
FRINGE_MIN_PIXELS = 8.0
#: ... in views this many pixels wide (the teacher's default width, where those measurements were made): the
#: threshold scales with the training views' width, so a teacher held at 2 x a small dataset's width
#: (:data:`MAX_UPSCALE`) decides as at 640. The from-ngp ball's 192-pixel cameras (teacher at 384): a 5.6 px
#: fringe, 9.3 px at 640; judged unscaled, its shell was left out and held-out PSNR at 1080p fell from 34.4 to
#: 30.8 dB (on an H200).
FRINGE_REFERENCE_WIDTH = 640

#: The soft-silhouette pass (``playback/silhouette.py``) runs when the field's fringe is at least this many
#: pixels wide at the playing resolution: it blends one pixel on each side of the mesh's edge. On a field with a
#: hard edge (an analytic sphere, 0.4 px) it cost 5.8 dB (35.3 -> 29.5 dB); on the NeuS fixture (3.1 px) it gained
#: 3.7 dB, on the demo (1.5 training px = 4.5 px at 1080p) 1.7 dB.
SILHOUETTE_BLEND_MIN_PIXELS = 1.5

#: Median angle in degrees between a mesh's plain vertex normals and its normals smoothed by
#: ``texture.normal_smoothing`` rounds above which the facing input reads the smoothed ones
#: (``choices.shading_normals``). Measured on 20 rounds: the Instant-NGP ball's fused-depth surface 14.6 (core) /
#: 8.9 (shell) degrees, smoothing gave 35.04 -> 37.19 dB; the gradient ball's level set 0.4 / 1.0 degrees, where
#: smoothing changed nothing it should and its held-out PSNR moved by the training's chaos (41.25 -> 40.61 dB).
ROUGH_NORMALS_DEG = 4.0
#: Rounds of smoothing :func:`choices.reflected_view_input` measures the normals' roughness with when
#: ``texture.normal_smoothing`` is 0 (the rounds ``ROUGH_NORMALS_DEG`` was measured on).
ROUGHNESS_ROUNDS = 20
#: Largest median turn (degrees, under 20 rounds of smoothing) of a mesh's normals at which the shader's direction
#: input is the view direction reflected about them (``texture.view_input`` "auto"). Measured, smoothed normals
#: fed: the demo bunny's level set 7.6 degrees (interior at 1080p +0.7 dB), the NeuS fixture's 6.3 (interior
#: +0.5), a surface fused from an Instant-NGP run's depths 39.6 (interior -0.2).
REFLECTION_MAX_ROUGHNESS_DEG = 20.0


def fringe_width_pixels(opacity: np.ndarray, lo: float = 0.05, hi: float = 0.95) -> float:
    """Mean width in pixels of the field's partly opaque fringe: pixels with ``lo < opacity < hi`` per pixel
    of silhouette (boundary pixels of ``opacity > 0.5``), over (N, H, W) opacities."""
    from scipy import ndimage

    op = np.asarray(opacity)
    solid = op > 0.5
    boundary = 0
    for view in solid:
        boundary += int((view & ~ndimage.binary_erosion(view)).sum())
    partial = int(((op > lo) & (op < hi)).sum())
    return partial / boundary if boundary else 0.0
