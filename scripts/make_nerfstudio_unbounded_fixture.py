#!/usr/bin/env python3
"""Train a nerfacto run of an unbounded 360-degree scene with nerfstudio's own trainer, and keep nerfstudio's
own renders of held-out views: the fixtures ``tests/data/nerfstudio/orbit360/`` (``--ground soft``, the default) and
``tests/data/nerfstudio/checker360/`` (``--ground checker``: a high-contrast checker ground to the horizon).

Run it with the Python of a scratch environment that has nerfstudio (never a dependency of this package)::

    python3 -m venv /path/to/nsenv && /path/to/nsenv/bin/pip install torch==2.13.0 nerfstudio==1.1.5
    /path/to/nsenv/bin/python scripts/make_nerfstudio_unbounded_fixture.py [--steps 1000] [--ground checker] [--out DIR]

Steps, each nerfstudio's own code:
1. the dataset: :mod:`unbounded_scene` ray-cast in closed form (objects on a ground plane that reaches a distant
   skyline, a sky gradient), 60 cameras on a full orbit, ``transforms.json`` + PNGs;
2. training: ``nerfstudio.scripts.train.main`` with the nerfacto method config (scene contraction, two proposal
   networks, appearance embedding, camera optimizer SO3xR3), on the CPU, with smaller hash tables than the
   defaults so the checkpoint stays small and fewer rays and samples a step so 2 cores train it in minutes, every 10th image held out (``eval_mode interval``);
3. reference renders: ``eval_setup`` + ``Model.get_outputs_for_camera`` of the held-out cameras (nerfstudio's
   proposal sampler, collider and ``last_sample`` background as trained);
4. the run folder as nerfstudio wrote it (``config.yml``, ``dataparser_transforms.json``, the checkpoint less
   its optimizer state), the dataset's ``transforms.json`` and ``reference_renders.npz`` (held-out image
   names, their data-frame poses, nerfstudio's RGB as uint8 and the seconds its renderer took for each view, with
   this script's torch threads) into ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

import unbounded_scene  # noqa: E402

NUM_VIEWS, WIDTH, HEIGHT, FOCAL = 60, 160, 120, 130.0
EVAL_INTERVAL = 10


def write_dataset(folder: Path, ground: str) -> None:
    """PNGs and transforms.json of the scene's orbit (OpenGL camera-to-world, nerfstudio's dataset format)."""
    from PIL import Image

    (folder / "images").mkdir(parents=True, exist_ok=True)
    poses = unbounded_scene.orbit_c2w(NUM_VIEWS)
    frames = []
    for i, c2w in enumerate(poses):
        name = f"images/frame_{i:03d}.png"
        image = unbounded_scene.render_view(c2w, WIDTH, HEIGHT, FOCAL, ground=ground)
        Image.fromarray(np.round(image * 255).astype(np.uint8)).save(folder / name)
        frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
    meta = {"camera_model": "OPENCV", "fl_x": FOCAL, "fl_y": FOCAL, "cx": WIDTH / 2, "cy": HEIGHT / 2,
            "w": WIDTH, "h": HEIGHT, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}
    (folder / "transforms.json").write_text(json.dumps(meta, indent=1))


def no_lpips() -> None:
    """nerfacto builds an LPIPS metric that downloads AlexNet weights; evaluation metrics are not needed here,
    so it becomes a module that returns 0 (nothing is downloaded)."""
    import torch
    import torchmetrics.image.lpip as lpip

    class NoLpips(torch.nn.Module):
        def __init__(self, *args, **kwargs):
            super().__init__()

        def forward(self, a, b):
            return torch.zeros(())

    lpip.LearnedPerceptualImagePatchSimilarity = NoLpips


#: Hash tables (log2 entries a level) of each ground's run. The checker run is nearer nerfstudio's defaults (2^14
#: of 16 levels) and stores its floats in half precision, so that its checkpoint stays under 2 MB too; its
#: reference renders are made with those rounded values.
HASHMAP_LOG2 = {"soft": 13, "checker": 14}
HALF_PRECISION = {"soft": False, "checker": True}


def train(data: Path, outputs: Path, steps: int, name: str, log2_hashmap_size: int):
    """nerfstudio's trainer on ``data``; returns the run folder."""
    import torch
    from nerfstudio.configs.method_configs import method_configs
    from nerfstudio.scripts.train import main as train_main

    torch.set_num_threads(1)     # one thread: a second one stalls at every sync when the other core is busy
    no_lpips()
    config = method_configs["nerfacto"]
    config.data = data
    config.output_dir = outputs
    config.experiment_name = name
    config.timestamp = "run"
    config.vis = "tensorboard"
    config.machine.device_type = "cpu"
    config.mixed_precision = False
    config.max_num_iterations = steps
    config.steps_per_save = 250     # a stopped training still leaves its latest checkpoint
    config.steps_per_eval_batch = 10**9
    config.steps_per_eval_image = 10**9
    config.steps_per_eval_all_images = 10**9
    config.save_only_latest_checkpoint = True
    dm = config.pipeline.datamanager
    dm.train_num_rays_per_batch = 512
    dm.eval_num_rays_per_batch = 512
    dm.dataparser.eval_mode = "interval"
    dm.dataparser.eval_interval = EVAL_INTERVAL
    model = config.pipeline.model
    model.implementation = "torch"
    model.log2_hashmap_size = log2_hashmap_size
    model.max_res = 1024
    model.proposal_net_args_list = [
        {"hidden_dim": 16, "log2_hashmap_size": 12, "num_levels": 5, "max_res": 128, "use_linear": False},
        {"hidden_dim": 16, "log2_hashmap_size": 12, "num_levels": 5, "max_res": 256, "use_linear": False},
    ]
    model.num_proposal_samples_per_ray = (128, 64)     # about a third of the defaults' work a step, on 2 cores
    model.num_nerf_samples_per_ray = 32
    model.eval_num_rays_per_chunk = 4096
    train_main(config)
    return outputs / name / "nerfacto" / "run"


def reference_renders(run: Path, data: Path, half: bool) -> dict:
    """nerfstudio's own renders of the held-out cameras: names, (N, 4, 4) data-frame poses, (N, H, W, 3) uint8,
    (N,) seconds each took."""
    import time

    import torch
    from nerfstudio.utils.eval_utils import eval_setup

    no_lpips()
    # nerfstudio 1.1.5 calls torch.load without weights_only, which torch >= 2.6 refuses for its numpy scalars;
    # this is the checkpoint this script just trained
    os.environ["TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD"] = "1"
    _, pipeline, _, _ = eval_setup(run / "config.yml", test_mode="test")
    if half:      # the values the stored checkpoint holds (:func:`pack`)
        with torch.no_grad():
            for p in pipeline.model.parameters():
                p.copy_(p.half().float())
    dataset = pipeline.datamanager.eval_dataset
    meta = json.loads((data / "transforms.json").read_text())
    poses = {f["file_path"]: np.asarray(f["transform_matrix"]) for f in meta["frames"]}
    names, c2ws, images, seconds = [], [], [], []
    for i, path in enumerate(dataset.image_filenames):
        rel = f"images/{Path(path).name}"
        t = time.perf_counter()
        with torch.no_grad():
            out = pipeline.model.get_outputs_for_camera(dataset.cameras[i:i + 1])
        seconds.append(time.perf_counter() - t)
        images.append(np.round(out["rgb"].clamp(0, 1).cpu().numpy() * 255).astype(np.uint8))
        names.append(rel)
        c2ws.append(poses[rel])
    return {"names": np.array(names), "c2w": np.stack(c2ws).astype(np.float64), "rgb": np.stack(images),
            "focal": np.float64(FOCAL), "seconds": np.asarray(seconds, dtype=np.float64),
            "threads": np.int64(torch.get_num_threads())}


def pack(run: Path, data: Path, out: Path, renders: dict, half: bool) -> None:
    """The run folder as nerfstudio wrote it (checkpoint less optimizer state) and the references into ``out``."""
    import torch

    out.mkdir(parents=True, exist_ok=True)
    shutil.copy(run / "config.yml", out / "config.yml")
    shutil.copy(run / "dataparser_transforms.json", out / "dataparser_transforms.json")
    shutil.copy(data / "transforms.json", out / "transforms.json")
    (out / "nerfstudio_models").mkdir(exist_ok=True)
    ckpt_path = sorted((run / "nerfstudio_models").glob("step-*.ckpt"))[-1]
    ckpt = torch.load(ckpt_path, weights_only=False, map_location="cpu")     # our own run: trusted
    state = ckpt["pipeline"]
    if half:
        state = {k: v.half() if torch.is_tensor(v) and v.dtype == torch.float32 else v for k, v in state.items()}
    slim = {"step": ckpt["step"], "pipeline": state}
    torch.save(slim, out / "nerfstudio_models" / ckpt_path.name)
    np.savez_compressed(out / "reference_renders.npz", **renders)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ground", choices=unbounded_scene.GROUNDS, default="soft")
    parser.add_argument("--out", type=Path, default=None, help="default tests/data/nerfstudio/orbit360 "
                        "(soft ground) or checker360 (checker ground)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads of nerfstudio's renders")
    parser.add_argument("--work", type=Path, default=None, help="where the dataset and nerfstudio's outputs go")
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    name = {"soft": "orbit360", "checker": "checker360"}[args.ground]
    out = args.out or ROOT / "tests/data/nerfstudio" / name
    work = args.work or Path(tempfile.mkdtemp(prefix=f"ns-{name}-"))
    data = work / "data"
    if not (data / "transforms.json").exists():
        write_dataset(data, args.ground)
    run = work / "outputs" / name / "nerfacto" / "run"
    if not (run / "nerfstudio_models").is_dir() or not any((run / "nerfstudio_models").glob("*.ckpt")):
        run = train(data, work / "outputs", args.steps, name, HASHMAP_LOG2[args.ground])
    import torch

    torch.set_num_threads(args.threads)
    renders = reference_renders(run, data, HALF_PRECISION[args.ground])
    pack(run, data, out, renders, HALF_PRECISION[args.ground])
    print(f"wrote {out} (work folder {work})")


if __name__ == "__main__":
    main()
