#!/usr/bin/env python3
"""Train a small nerfacto field with nerfstudio's own code and save it as a nerfstudio run folder.

The result, ``tests/data/nerfstudio/bunny/`` (``config.yml``, ``nerfstudio_models/step-*.ckpt``,
``dataparser_transforms.json``, the dataset's ``transforms.json`` and ``reference_points.npz``), is the fixture
of ``neuras-distill from-nerfstudio``: the weights are those of nerfstudio's ``NerfactoField`` class itself
(``implementation="torch"``, the layout nerfstudio writes without tiny-cuda-nn), trained on this machine.

How (a throwaway environment, not this package's): nerfstudio 1.1.5's wheel is unpacked (``--nerfstudio-src``,
or ``pip download nerfstudio==1.1.5 --no-deps`` into a temporary folder) and imported with ``jaxtyping`` and
``rich`` (``pip install --target``); the modules the field never calls (the viewer's ``viser``, tensorboard,
wandb, ...) are replaced by empty stand-ins. nerfstudio's trainer, data manager and proposal sampler are not
used (they pull in gsplat, nerfacc, open3d, the viewer and more; installing them was not attempted): the field
is trained here on rays
of the embedded bunny's renders with stratified samples inside the bunny's box, volume-rendered with nerfstudio's
own ``RaySamples.get_weights``, L2 against the renders (white background, the config's ``background_color``)
plus nerfacto's distortion loss (nerfstudio's ``distortion_loss``, weight 0.002 as nerfacto's default: without it
a 1200-step fixture was a fog around the bunny, 22-24 dB against the scene; with it and 3000
steps, 27-29 dB and a surface),
Adam as nerfacto's ``fields`` optimizer (lr 1e-2, eps 1e-15; its learning rates are stored as ``numpy.float64``
as nerfstudio's scheduler leaves them, so the checkpoint has the numpy pickle globals real ones have). The
proposal networks in the checkpoint are nerfstudio's ``HashMLPDensityField`` at their initial weights
(distillation does not use them).

Frames, as nerfstudio's data parser sets them: the dataset's cameras (``transforms.json``, OpenGL convention,
the bunny's world frame, units of the scene) are rotated by ``ROTATION_DEG`` about z, centred on the cameras'
mean and scaled so every camera lies inside [-1, 1]^3 (``auto_scale_poses``); ``dataparser_transforms.json``
holds that ``transform`` (3x4) and ``scale``. ``reference_points.npz`` holds nerfstudio's own density and
colour (eval mode, the mean appearance embedding) at points of the scene box, for the adapter's parity test.

Usage:
    python scripts/make_nerfstudio_fixture.py [--out tests/data/nerfstudio/bunny] [--steps 3000] [--seed 0]
        [--threads 2] [--nerfstudio-src DIR] [--deps DIR]

The optimizer state keeps its parameter groups (with their numpy learning rates) but not Adam's moments, which
would triple the fixture's size.
"""

from __future__ import annotations

import argparse
import importlib.abc
import importlib.machinery
import json
import math
import subprocess
import sys
import tempfile
import time
import types
import zipfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

NERFSTUDIO_VERSION = "1.1.5"
ROTATION_DEG = 30.0
LOG2_HASHMAP = 13            # 2^13 entries per level: the checkpoint stays under 2 MB (2^14: 2.49 MB)
NUM_VIEWS, WIDTH, HEIGHT = 40, 128, 128
SAMPLES_PER_RAY = 64
DISTORTION_MULT = 0.002       # nerfacto's distortion_loss_mult: keeps each ray's weight compact (no fog)
RAYS_PER_STEP = 1024
WARMUP_STEPS = 200
#: modules nerfstudio imports at the top of files the field needs, but never calls for it
STAND_INS = ("viser", "tensorboard", "wandb", "comet_ml", "tyro", "plotly", "mediapy", "cv2", "imageio", "av",
             "torch.utils.tensorboard")


class _StandIns(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Empty modules for :data:`STAND_INS`: any attribute is a class that accepts anything."""

    def find_spec(self, name, path, target=None):
        if any(name == s or name.startswith(s + ".") for s in STAND_INS):
            return importlib.machinery.ModuleSpec(name, self, is_package=True)
        return None

    def create_module(self, spec):
        module = types.ModuleType(spec.name)
        module.__path__ = []
        def stand_in(attr: str):
            if attr.startswith("__"):
                raise AttributeError(attr)
            return type(attr, (), {"__init__": lambda self, *a, **k: None})

        module.__getattr__ = stand_in
        module.__file__ = f"<stand-in {spec.name}>"
        return module

    def exec_module(self, module):
        pass


def import_nerfstudio(src: Path | None, deps: Path | None, work: Path):
    """nerfstudio's field classes, from an unpacked wheel (downloaded with pip when ``src`` is None)."""
    if src is None:
        subprocess.run([sys.executable, "-m", "pip", "download", f"nerfstudio=={NERFSTUDIO_VERSION}", "--no-deps",
                        "-d", str(work), "-q"], check=True)
        wheel = next(work.glob("nerfstudio-*.whl"))
        src = work / "src"
        zipfile.ZipFile(wheel).extractall(src)
    if deps is None:
        deps = work / "deps"
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--target", str(deps), "jaxtyping", "rich"],
                       check=True)
    sys.path[:0] = [str(src), str(deps)]
    sys.meta_path.insert(0, _StandIns())
    import nerfstudio
    from nerfstudio.cameras.rays import Frustums, RaySamples
    from nerfstudio.field_components.field_heads import FieldHeadNames
    from nerfstudio.field_components.spatial_distortions import SceneContraction
    from nerfstudio.fields.density_fields import HashMLPDensityField
    from nerfstudio.fields.nerfacto_field import NerfactoField
    from nerfstudio.model_components.losses import distortion_loss

    return types.SimpleNamespace(version=getattr(nerfstudio, "__version__", NERFSTUDIO_VERSION), Frustums=Frustums,
                                 RaySamples=RaySamples, FieldHeadNames=FieldHeadNames,
                                 SceneContraction=SceneContraction, HashMLPDensityField=HashMLPDensityField,
                                 NerfactoField=NerfactoField, distortion_loss=distortion_loss)


def dataparser_transform(c2w: np.ndarray) -> tuple[np.ndarray, float]:
    """(3x4 transform, scale): rotate about z, centre on the cameras, scale the cameras into [-1, 1]^3."""
    a = math.radians(ROTATION_DEG)
    rot = np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
    centre = c2w[:, :3, 3].mean(axis=0)
    transform = np.concatenate([rot, (-rot @ centre)[:, None]], axis=1)
    moved = (rot @ (c2w[:, :3, 3] - centre).T).T
    scale = 1.0 / float(np.abs(moved).max())
    return transform, scale


def to_nerfstudio(points: np.ndarray, transform: np.ndarray, scale: float) -> np.ndarray:
    return scale * (points @ transform[:, :3].T + transform[:, 3])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=ROOT / "tests/data/nerfstudio/bunny")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--nerfstudio-src", type=Path, default=None, help="an unpacked nerfstudio wheel")
    parser.add_argument("--deps", type=Path, default=None, help="a --target folder with jaxtyping and rich")
    args = parser.parse_args()
    torch.manual_seed(args.seed)
    np.random.seed(args.seed)
    torch.set_num_threads(args.threads)

    from neuras_distill.render.volume import VolumeRenderer
    from neuras_distill.scenes.synthetic import make_scene

    work = Path(tempfile.mkdtemp(prefix="nsfixture-"))
    ns = import_nerfstudio(args.nerfstudio_src, args.deps, work)

    # ---- data: the bunny's renders (world frame), white background
    scene = make_scene("bunny")
    cams = scene.default_cameras(NUM_VIEWS, WIDTH, HEIGHT)
    teacher = VolumeRenderer(scene, num_steps=192)
    images, t0 = [], time.perf_counter()
    for i in range(len(cams)):
        images.append(teacher.render(cams, i)["rgb"])
    print(f"rendered {len(cams)} views at {WIDTH}x{HEIGHT} in {time.perf_counter() - t0:.0f} s", flush=True)
    c2w = cams.c2w.double().numpy()
    transform, scale = dataparser_transform(c2w)

    origins, dirs, colours, view_ids = [], [], [], []
    for i in range(len(cams)):
        o, d = cams.rays(i)
        o_ns = to_nerfstudio(o.reshape(-1, 3).double().numpy(), transform, scale)
        d_ns = d.reshape(-1, 3).double().numpy() @ transform[:, :3].T
        origins.append(o_ns)
        dirs.append(d_ns / np.linalg.norm(d_ns, axis=1, keepdims=True))
        colours.append(images[i].reshape(-1, 3))
        view_ids.append(np.full(o_ns.shape[0], i))
    origins = torch.from_numpy(np.concatenate(origins)).float()
    dirs = torch.from_numpy(np.concatenate(dirs)).float()
    colours = torch.from_numpy(np.concatenate(colours)).float()
    view_ids = torch.from_numpy(np.concatenate(view_ids)).long()

    # ---- nerfstudio's field (nerfacto defaults but a 2^14 table), scene box [-1, 1]^3, L-inf contraction
    aabb = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = ns.NerfactoField(aabb, num_images=len(cams), log2_hashmap_size=LOG2_HASHMAP,
                             spatial_distortion=ns.SceneContraction(order=float("inf")),
                             use_average_appearance_embedding=True, average_init_density=0.01,
                             implementation="torch")
    proposals = [ns.HashMLPDensityField(aabb, spatial_distortion=ns.SceneContraction(order=float("inf")),
                                        num_levels=5, max_res=res, log2_hashmap_size=12, implementation="torch",
                                        average_init_density=0.01)
                 for res in (128, 256)]
    opt = torch.optim.Adam(field.parameters(), lr=1e-2, eps=1e-15)
    # samples only inside the bunny's box (grown 5%), in nerfstudio's frame: rays that miss it see the background
    corners = np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=np.float64)
    box = scene.aabb.double().numpy()
    grown = box + np.array([[-1.0], [1.0]]) * 0.05 * (box[1] - box[0])
    ns_corners = to_nerfstudio(grown[0] + corners * (grown[1] - grown[0]), transform, scale)
    box_lo = torch.from_numpy(ns_corners.min(0)).float()
    box_hi = torch.from_numpy(ns_corners.max(0)).float()

    def render(o, d, ids, train: bool):
        n = o.shape[0]
        inv = 1.0 / torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
        t0, t1 = (box_lo - o) * inv, (box_hi - o) * inv
        near = torch.minimum(t0, t1).amax(-1).clamp(min=0.05)
        far = torch.maximum(t0, t1).amin(-1).clamp(min=0.06)
        far = torch.maximum(far, near + 1e-3)
        u = (torch.arange(SAMPLES_PER_RAY) + (torch.rand(n, SAMPLES_PER_RAY) if train else 0.5)) / SAMPLES_PER_RAY
        width = ((far - near) / SAMPLES_PER_RAY)[:, None].expand(n, SAMPLES_PER_RAY)
        mids = near[:, None] + u * (far - near)[:, None]
        starts, ends = (mids - 0.5 * width)[..., None], (mids + 0.5 * width)[..., None]
        frustums = ns.Frustums(origins=o[:, None].expand(n, SAMPLES_PER_RAY, 3),
                               directions=d[:, None].expand(n, SAMPLES_PER_RAY, 3), starts=starts, ends=ends,
                               pixel_area=torch.ones(n, SAMPLES_PER_RAY, 1))
        span = (far - near)[:, None, None]
        samples = ns.RaySamples(frustums=frustums, camera_indices=ids[:, None, None].expand(n, SAMPLES_PER_RAY, 1),
                                deltas=ends - starts, spacing_starts=(starts - near[:, None, None]) / span,
                                spacing_ends=(ends - near[:, None, None]) / span)
        out = field(samples)
        w = samples.get_weights(out[ns.FieldHeadNames.DENSITY])
        rgb = (w * out[ns.FieldHeadNames.RGB]).sum(1)
        return rgb + (1.0 - w.sum(1)).clamp(min=0.0), w, samples       # white background

    field.train()
    gen = torch.Generator().manual_seed(args.seed)
    t0 = time.perf_counter()
    for step in range(1, args.steps + 1):
        # nerfstudio's ExponentialDecayScheduler with a warm-up (lr_pre_warmup 1e-8 -> 1e-2 over WARMUP_STEPS, then
        # exponential decay to 1e-4 at the last step); without the warm-up the colour head died on this data
        # (every ReLU off, sigmoid output 0: a grey field that only matched brightness)
        if step <= WARMUP_STEPS:
            lr = 1e-8 + (1e-2 - 1e-8) * step / WARMUP_STEPS
        else:
            lr = float(np.exp(np.log(1e-2) + (np.log(1e-4) - np.log(1e-2)) * (step - WARMUP_STEPS)
                              / max(1, args.steps - WARMUP_STEPS)))
        for group in opt.param_groups:
            group["lr"] = lr
        pick = torch.randint(0, origins.shape[0], (RAYS_PER_STEP,), generator=gen)
        rgb, weights, samples = render(origins[pick], dirs[pick], view_ids[pick], True)
        mse = torch.mean((rgb - colours[pick]) ** 2)
        loss = mse + DISTORTION_MULT * ns.distortion_loss([weights], [samples])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if step % 50 == 0 or step == args.steps:
            print(f"step {step}: PSNR {-10 * math.log10(float(mse)):.2f} dB ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    field.eval()

    # ---- reference evaluations (nerfstudio's own code, eval mode) at points of the box
    with torch.no_grad():
        box = torch.rand(4096, 3, generator=gen) * 1.6 - 0.8
        rd = torch.nn.functional.normalize(torch.randn(4096, 3, generator=gen), dim=-1)
        frustums = ns.Frustums(origins=box[:, None], directions=rd[:, None], starts=torch.zeros(4096, 1, 1),
                               ends=torch.zeros(4096, 1, 1), pixel_area=torch.ones(4096, 1, 1))
        samples = ns.RaySamples(frustums=frustums, camera_indices=torch.zeros(4096, 1, 1, dtype=torch.long))
        out = field(samples)
        density = out[ns.FieldHeadNames.DENSITY].reshape(-1).numpy()
        rgb = out[ns.FieldHeadNames.RGB].reshape(-1, 3).numpy()

    # ---- write the run folder as nerfstudio lays it out
    out = args.out
    (out / "nerfstudio_models").mkdir(parents=True, exist_ok=True)
    state = {f"_model.field.{k}": v for k, v in field.state_dict().items()}
    for i, prop in enumerate(proposals):
        state.update({f"_model.proposal_networks.{i}.{k}": v for k, v in prop.state_dict().items()})
    state["_model.field_coarse"] = None
    state = {k: v for k, v in state.items() if v is not None}
    for group in opt.param_groups:        # nerfstudio's LambdaLR scheduler leaves numpy.float64 learning rates
        group["lr"] = np.float64(group["lr"])
    optimizer = opt.state_dict()
    optimizer["state"] = {}                   # Adam's moments would triple the fixture's size; nothing reads them
    ckpt = {"step": args.steps, "pipeline": state, "optimizers": {"fields": optimizer},
            "schedulers": {}, "scalers": {"scale": 65536.0, "growth_factor": 2.0, "backoff_factor": 0.5,
                                          "growth_interval": 2000, "_growth_tracker": 0}}
    torch.save(ckpt, out / "nerfstudio_models" / f"step-{args.steps - 1:09d}.ckpt")
    (out / "dataparser_transforms.json").write_text(json.dumps(
        {"transform": transform.tolist(), "scale": scale}, indent=4))
    focal = float(cams.fx[0]) if hasattr(cams, "fx") else None
    frames = [{"file_path": f"images/frame_{i:05d}.png", "transform_matrix": c2w[i].tolist()}
              for i in range(len(cams))]
    (out / "transforms.json").write_text(json.dumps(
        {"w": WIDTH, "h": HEIGHT, "fl_x": focal, "fl_y": focal, "cx": WIDTH / 2, "cy": HEIGHT / 2,
         "camera_model": "OPENCV", "frames": frames}, indent=1))
    np.savez_compressed(out / "reference_points.npz", positions=box.numpy(), directions=rd.numpy(),
                        density=density, rgb=rgb)
    (out / "config.yml").write_text(CONFIG_TEMPLATE.format(
        steps=args.steps, log2=LOG2_HASHMAP, num_images=len(cams), version=ns.version))
    print(f"wrote {out}: " + ", ".join(f"{p.relative_to(out)} {p.stat().st_size / 1e6:.2f} MB"
                                        for p in sorted(out.rglob('*')) if p.is_file()))


#: config.yml as nerfstudio 1.1.x dumps it (``yaml.dump`` of the TrainerConfig dataclasses), trimmed to the
#: sections a reader needs; the values are the ones this script trained with.
CONFIG_TEMPLATE = """!!python/object:nerfstudio.engine.trainer.TrainerConfig
_target: !!python/name:nerfstudio.engine.trainer.Trainer ''
data: !!python/object/apply:pathlib.PosixPath
- data
- bunny
experiment_name: bunny
gradient_accumulation_steps: {{}}
load_checkpoint: null
load_config: null
load_dir: null
load_scheduler: true
load_step: null
log_gradients: false
logging: !!python/object:nerfstudio.configs.base_config.LoggingConfig
  local_writer: !!python/object:nerfstudio.configs.base_config.LocalWriterConfig
    _target: !!python/name:nerfstudio.utils.writer.LocalWriter ''
    enable: true
    max_log_size: 10
    stats_to_track: !!python/tuple
    - !!python/object/apply:nerfstudio.utils.writer.EventName
      - Train Iter (time)
    - !!python/object/apply:nerfstudio.utils.writer.EventName
      - Train Rays / Sec
  max_buffer_size: 20
  profiler: basic
  relative_log_dir: !!python/object/apply:pathlib.PosixPath []
  steps_per_log: 10
machine: !!python/object:nerfstudio.configs.base_config.MachineConfig
  device_type: cpu
  dist_url: auto
  machine_rank: 0
  num_devices: 1
  num_machines: 1
  seed: 42
max_num_iterations: {steps}
method_name: nerfacto
mixed_precision: false
optimizers:
  fields:
    optimizer: !!python/object:nerfstudio.engine.optimizers.AdamOptimizerConfig
      _target: &id001 !!python/name:torch.optim.adam.Adam ''
      eps: 1.0e-15
      lr: 0.01
      max_norm: null
      weight_decay: 0
    scheduler: !!python/object:nerfstudio.engine.schedulers.ExponentialDecaySchedulerConfig
      _target: &id002 !!python/name:nerfstudio.engine.schedulers.ExponentialDecayScheduler ''
      lr_final: 0.0001
      lr_pre_warmup: 1.0e-08
      max_steps: {steps}
      ramp: linear
      warmup_steps: 200
output_dir: !!python/object/apply:pathlib.PosixPath
- outputs
pipeline: !!python/object:nerfstudio.pipelines.base_pipeline.VanillaPipelineConfig
  _target: !!python/name:nerfstudio.pipelines.base_pipeline.VanillaPipeline ''
  datamanager: !!python/object:nerfstudio.data.datamanagers.parallel_datamanager.ParallelDataManagerConfig
    _target: !!python/name:nerfstudio.data.datamanagers.parallel_datamanager.ParallelDataManager ''
    camera_res_scale_factor: 1.0
    data: null
    dataparser: !!python/object:nerfstudio.data.dataparsers.nerfstudio_dataparser.NerfstudioDataParserConfig
      _target: !!python/name:nerfstudio.data.dataparsers.nerfstudio_dataparser.Nerfstudio ''
      auto_scale_poses: true
      center_method: poses
      data: !!python/object/apply:pathlib.PosixPath []
      depth_unit_scale_factor: 0.001
      downscale_factor: null
      eval_mode: fraction
      orientation_method: none
      scale_factor: 1.0
      scene_scale: 1.0
      train_split_fraction: 0.9
    eval_image_indices: !!python/tuple
    - 0
    eval_num_rays_per_batch: 4096
    train_num_rays_per_batch: {rays}
  model: !!python/object:nerfstudio.models.nerfacto.NerfactoModelConfig
    _target: !!python/name:nerfstudio.models.nerfacto.NerfactoModel ''
    appearance_embed_dim: 32
    average_init_density: 0.01
    background_color: white
    base_res: 16
    camera_optimizer: !!python/object:nerfstudio.cameras.camera_optimizers.CameraOptimizerConfig
      mode: 'off'
      rot_l2_penalty: 0.001
      trans_l2_penalty: 0.01
    collider_params:
      far_plane: 1000.0
      near_plane: 0.05
    disable_scene_contraction: false
    distortion_loss_mult: 0.002
    enable_collider: true
    eval_num_rays_per_chunk: 32768
    far_plane: 1000.0
    features_per_level: 2
    hidden_dim: 64
    hidden_dim_color: 64
    hidden_dim_transient: 64
    implementation: torch
    interlevel_loss_mult: 1.0
    log2_hashmap_size: {log2}
    max_res: 2048
    near_plane: 0.05
    num_levels: 16
    num_nerf_samples_per_ray: 48
    num_proposal_iterations: 2
    num_proposal_samples_per_ray: !!python/tuple
    - 256
    - 96
    orientation_loss_mult: 0.0001
    pred_normal_loss_mult: 0.001
    predict_normals: false
    proposal_initial_sampler: piecewise
    proposal_net_args_list:
    - hidden_dim: 16
      log2_hashmap_size: 12
      max_res: 128
      num_levels: 5
      use_linear: false
    - hidden_dim: 16
      log2_hashmap_size: 12
      max_res: 256
      num_levels: 5
      use_linear: false
    proposal_update_every: 5
    proposal_warmup: 5000
    proposal_weights_anneal_max_num_iters: 1000
    proposal_weights_anneal_slope: 10.0
    use_average_appearance_embedding: true
    use_gradient_scaling: false
    use_proposal_weight_anneal: true
    use_same_proposal_network: false
    use_single_jitter: true
project_name: nerfstudio-project
prompt: null
relative_model_dir: !!python/object/apply:pathlib.PosixPath
- nerfstudio_models
save_only_latest_checkpoint: true
steps_per_eval_all_images: 25000
steps_per_eval_batch: 500
steps_per_eval_image: 500
steps_per_save: 2000
timestamp: 2026-11-25_000000
use_grad_scaler: false
viewer: !!python/object:nerfstudio.configs.base_config.ViewerConfig
  quit_on_train_completion: true
vis: viewer
""".replace("{rays}", str(RAYS_PER_STEP))


if __name__ == "__main__":
    main()
