"""Fitting a :class:`NeuralTextureModel` to teacher images through rasterized G-buffers.

Owns: :func:`fit` and :class:`TrainLog`.

Decisions:
- Batches are random square patches (``patch`` x ``patch``) centred on random covered pixels of random views
  (clamped into the image); the loss is ``L2 on covered pixels + ssim_weight * (1 - SSIM) + vq_weight * vq_loss``.
  ``ssim_weight`` defaults to 0: with 0.2 the SSIM gradient dominated and colours came out desaturated
  (1.2 dB lower held-out PSNR on the instant-nsr-pl fixture, 1.5-2 dB on the street scene).
  For SSIM the uncovered pixels of the prediction are set to the target, and the SSIM map is averaged over
  covered window centres.
- Optimisers: the texture (H*W*D, mostly untouched by a step) uses ``SparseAdam`` on sparse gradients, so a
  step costs O(batch), not O(atlas); MLP and codebook use Adam at ``lr`` (0.01, the paper's), the texture at
  ``texture_lr_scale`` x lr (9: each texel sees only a few samples per step while the MLP gets dense
  gradients every step; on the first synthetic test 3x gained ~3-6 dB at equal steps over 1x; on the
  Instant-NGP ball with exact codes, 9586 steps, held out: 3x 37.47, 9x 37.71, 30x 37.30 dB interior).
  The MLP at lr/2 was ~2 dB worse.
  Both decay exponentially to 0.1x over the run (progress = max(step/steps, elapsed/time_budget_s)).
- VQ schedule: the first ``vq_warmup`` fraction of the run trains continuous features; then the codebook is
  k-means-initialised from the touched texels and the model is quantized from there on. The default 1.0
  quantizes once, after training: k-means of the trained texels, and the codes are exactly what is evaluated
  and baked. Training under quantization (straight-through) from 15 % of a short run cost 1.4 dB on the NeuS
  fixture (29.1 vs 30.6 dB held-out, 1500 steps) and 1.3 dB on the instant-nsr-pl one, with paler colours:
  a texel's quantized value only changes when its feature crosses into another code's cell, so most of the
  run trained the atlas at a fraction of its speed. k-means of the continuously trained atlas (1024 codes)
  lost 0.0-0.1 dB against the continuous atlas (``benchmarks/vq_schedule.py``).
- Touched texels are recorded all along; at the end untouched texels get the nearest touched feature
  (:meth:`NeuralTextureModel.fill_unseen_texels`).
- Skyboxes (optional ``skybox``): patches are then centred on any pixel, every pixel of a patch counts, and
  pixels the mesh does not cover are coloured by the :class:`SkyboxModel` from the view's camera centre and
  the pixel's direction. The skybox atlas joins the sparse optimiser, its shader and codebook the dense one;
  its quantizer starts with the mesh's.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import numpy as np
import torch
from tqdm import tqdm

from neuras_distill.config import TrainConfig
from neuras_distill.errors import BadInputError
from neuras_distill.neural.data_parallel import GradientExchange
from neuras_distill.neural.losses import ssim
from neuras_distill.neural.model import NeuralTextureModel

#: The library's defaults are the configuration's (one place: ``config.py``).
_TRAIN = TrainConfig()


@dataclass
class TrainLog:
    """What ``fit`` did.

    Attributes:
        entries: [{"step", "seconds", "loss", "psnr" (batch, covered pixels), "lr", and when quantizing
            "perplexity", "used_fraction"}] at every ``log_every`` steps and at the last step.
        steps: optimisation steps done; seconds: wall time of the loop; steps_per_second.
        stopped_by: "steps" or "time_budget".
        vq_start_step: step at which quantization began (None without VQ).
        vq_stats: final quantizer stats (perplexity, used_fraction, ...), {} without VQ.
        exact_codes: quantization was skipped: no more texels were touched than ``model.quantize_above``.
        touched_fraction: fraction of texels a training sample touched; filled_texels: texels gutter-filled.
        processes: ranks that trained together (``exchange``); pixels_per_second_per_process: batch pixels
            (patches x patch²) per second of the loop, divided by ``processes``.
    """

    entries: list = field(default_factory=list)
    steps: int = 0
    seconds: float = 0.0
    steps_per_second: float = 0.0
    stopped_by: str = "steps"
    vq_start_step: int | None = None
    vq_stats: dict = field(default_factory=dict)
    exact_codes: bool = False
    touched_fraction: float = 0.0
    filled_texels: int = 0
    sky_touched_fraction: float | None = None
    resumed_from_step: int | None = None
    checkpoints_written: int = 0
    processes: int = 1
    pixels_per_second_per_process: float = 0.0

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _as_tensor(x, dtype, name: str, shape_tail: tuple, lead: tuple | None = None) -> torch.Tensor:
    t = torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x)
    if t.dim() != 3 + len(shape_tail) or tuple(t.shape[3:]) != shape_tail:
        raise BadInputError(f"fit: {name} must have shape (N, H, W{''.join(', ' + str(s) for s in shape_tail)}), "
                            f"got {tuple(t.shape)}")
    if lead is not None and tuple(t.shape[:3]) != lead:
        raise BadInputError(f"fit: {name} has shape {tuple(t.shape)}, expected leading (N, H, W) = {lead}")
    return t.to(dtype)


def fit(model: NeuralTextureModel, uv, coverage, dirs, targets, *, steps: int, lr: float = _TRAIN.lr,
        texture_lr_scale: float = _TRAIN.texture_lr_scale,
        batch_patches: int = _TRAIN.batch_patches, patch: int = _TRAIN.patch,
        ssim_weight: float = _TRAIN.ssim_weight, vq_weight: float = 1.0, vq_warmup: float = _TRAIN.vq_warmup,
        lr_final_ratio: float = 0.1,
        time_budget_s: float | None = None, progress: bool = True, log_every: int | None = None,
        seed: int = _TRAIN.seed, num_threads: int | None = None, skybox=None, origins=None,
        sky_pixels=None, checkpoint=None, device: torch.device | str | None = None,
        exchange: GradientExchange | None = None) -> TrainLog:
    """Train ``model`` on teacher images.

    Args:
        uv: (N, H, W, 2) float32 G-buffer texture coordinates; coverage: (N, H, W) bool;
        dirs: (N, H, W, C) float32 view inputs, C = ``model.view_columns`` (unit directions, the facing cosine
            when the shader uses it, the mesh layer with two layers: ``neural.model.view_inputs``);
            targets: (N, H, W, 3) float32 teacher colours.
        steps: maximum optimisation steps; time_budget_s: optional wall-clock limit (whichever comes first).
        lr: MLP and codebook learning rate; texture_lr_scale: the atlases (the mesh's and the skyboxes')
            learn at this multiple of lr.
        batch_patches, patch: patches per step and their side in pixels.
        ssim_weight, vq_weight: loss weights; vq_warmup: fraction of the run before quantization starts
            (1.0: quantize after training).
        log_every: steps between log entries (default steps // 50).
        num_threads: torch intra-op threads during the loop (restored after); None leaves torch's setting.
            On a busy shared CPU, 1 thread avoids OpenMP oversubscription (measured 108 vs 1.8 steps/s).
        skybox: optional :class:`SkyboxModel` trained jointly on the pixels the mesh does not cover.
        origins: (N, 3) float32 camera centres relative to ``skybox.layers.center`` (required with skybox).
        sky_pixels: optional (N, H, W) bool, the uncovered pixels the skybox learns from (default: all of them);
            an uncovered pixel outside it is left out of the loss (``pipeline.decisions.near_miss_pixels``: the
            field shows a surface there that the mesh missed, which the skybox must not smear over the sky).
        checkpoint: optional :class:`neural.train_checkpoint.TrainCheckpoint`: the loop starts from its stored
            state when it has one (``TrainLog.resumed_from_step``) and saves its state when it is due.
        device: where the model (and skybox) train; None: where the model is. The G-buffers and targets stay in
            host memory: each step's batch is drawn there (same random numbers on every device) and sent over.
        exchange: this process's :class:`~neuras_distill.neural.data_parallel.GradientExchange` when ``fit`` runs
            on several ranks at once (every rank with the same model, arrays and seed): each computes its share
            of every batch and the gradients are summed; None: one process.
    Returns:
        :class:`TrainLog`. The model (and skybox) is left on the host in eval mode with untouched texels filled
        (on rank 0; the other ranks of an ``exchange`` return right after the loop, their model unquantized).
    """
    if steps < 1:
        raise BadInputError(f"fit: steps must be >= 1, got {steps}")
    cov = _as_tensor(coverage, torch.bool, "coverage", ())
    lead = tuple(cov.shape)
    uv_t = _as_tensor(uv, torch.float32, "uv", (2,), lead)
    dirs_t = _as_tensor(dirs, torch.float32, "dirs", (model.view_columns,), lead)
    tgt_t = _as_tensor(targets, torch.float32, "targets", (3,), lead)
    n, h, w = lead
    cov_f = cov.reshape(-1)
    covered = torch.nonzero(cov_f).flatten()
    if covered.numel() == 0:
        raise BadInputError("fit: no pixel is covered by the mesh in any training view")
    if skybox is not None:
        if origins is None:
            raise BadInputError("fit: a skybox needs the camera centres (origins) of the training views")
        origins_t = torch.as_tensor(np.asarray(origins, dtype=np.float32)).reshape(-1, 3)
        if origins_t.shape[0] != lead[0]:
            raise BadInputError(f"fit: origins has {origins_t.shape[0]} rows for {lead[0]} views")
        covered = torch.arange(cov_f.numel())            # patches anywhere: the sky is trained too
    sky_f = None
    if skybox is not None:                               # uncovered pixels the sky learns from (default: all)
        sky_f = (torch.ones(cov_f.numel(), dtype=torch.bool) if sky_pixels is None
                 else _as_tensor(sky_pixels, torch.bool, "sky_pixels", (), lead).reshape(-1))
    uv_f, dirs_f, tgt_f = uv_t.reshape(-1, 2), dirs_t.reshape(-1, dirs_t.shape[-1]), tgt_t.reshape(-1, 3)

    p = int(max(1, min(patch, h, w)))
    device = torch.device(device) if device is not None else model.texture.data.device
    model.to(device)
    if skybox is not None:
        skybox.to(device)
        origins_t = origins_t.to(device)
    gen = torch.Generator().manual_seed(seed)
    dy, dx = torch.meshgrid(torch.arange(p), torch.arange(p), indexing="ij")
    use_ssim = ssim_weight > 0 and p >= 7
    log_every = max(1, steps // 50) if log_every is None else max(1, int(log_every))
    texture_lr = texture_lr_scale * lr

    tex_params = [model.texture.data]
    dense_groups = [{"params": list(model.shaders.parameters()), "lr": lr}]
    if model.vq is not None:
        dense_groups.append({"params": [model.vq.codebook], "lr": lr})
    models = [model]
    if skybox is not None:
        tex_params.append(skybox.atlas.texture.data)
        dense_groups.append({"params": skybox.dense_parameters(), "lr": lr})
        models.append(skybox.atlas)
    if model.sparse_grad:
        opt_tex = torch.optim.SparseAdam(tex_params, lr=texture_lr)
    else:
        opt_tex = torch.optim.Adam(tex_params, lr=texture_lr)
    opt = torch.optim.Adam(dense_groups)
    base_lrs = [[g["lr"] for g in o.param_groups] for o in (opt_tex, opt)]

    log = TrainLog()
    old_threads = torch.get_num_threads()
    if num_threads is not None:
        torch.set_num_threads(int(num_threads))
    model.train()
    if skybox is not None:
        skybox.train()
    for m_ in models:
        m_.record_touched = True
    bar = tqdm(total=steps, file=sys.stderr, disable=not progress, desc="distill", leave=False)
    t0 = time.perf_counter()
    step = 0
    stored = checkpoint.load() if checkpoint is not None else None
    if stored is not None:
        step = _restore(stored, model, skybox, models, opt_tex, opt, gen, log)
        t0 -= float(stored["elapsed"])
        bar.update(step)
    shared_clock = float(stored["elapsed"]) if stored is not None else 0.0   # rank 0's, one step late
    sparse_params = tex_params if model.sparse_grad else []
    dense_params = [q for g in dense_groups for q in g["params"]] + ([] if model.sparse_grad else tex_params)
    try:
        while step < steps:
            elapsed = time.perf_counter() - t0 if exchange is None else shared_clock
            frac = step / steps
            if time_budget_s is not None:
                if elapsed >= time_budget_s:
                    log.stopped_by = "time_budget"
                    break
                frac = max(frac, elapsed / time_budget_s)
            if model.use_vq and not model.quantizing and vq_warmup < 1.0 and frac >= vq_warmup:
                for m_ in models:
                    _start_vq(m_, exchange)
                log.vq_start_step = step
            decay = lr_final_ratio ** min(frac, 1.0)
            for o, bases in zip((opt_tex, opt), base_lrs):
                for g, b in zip(o.param_groups, bases):
                    g["lr"] = b * decay

            # ---- batch of patches centred on covered pixels
            c = covered[torch.randint(0, covered.numel(), (batch_patches,), generator=gen)]
            view = torch.div(c, h * w, rounding_mode="floor")
            rem = c - view * (h * w)
            cy = torch.div(rem, w, rounding_mode="floor")
            cx = rem - cy * w
            top = (cy - p // 2).clamp(0, h - p)
            left = (cx - p // 2).clamp(0, w - p)
            pix = (view[:, None, None] * (h * w) + (top[:, None, None] + dy) * w + (left[:, None, None] + dx))
            # counts of the whole batch (every rank's share): each rank's terms are normalised by them
            whole = _BatchCounts.of(cov_f[pix.reshape(-1)], None if sky_f is None else sky_f[pix.reshape(-1)])
            mine = exchange.share(batch_patches) if exchange is not None else torch.arange(batch_patches)
            pix, view = pix[mine].reshape(-1), view[mine]
            m, tgt = cov_f[pix].to(device), tgt_f[pix].to(device)
            uv_b, dirs_b = uv_f[pix].to(device), dirs_f[pix].to(device)
            sel = torch.nonzero(m).flatten()
            rgb, aux = model(uv_b[sel], dirs_b[sel])
            vq_loss = aux["vq_loss"] * (sel.numel() / max(whole.mesh, 1))
            if skybox is not None:                    # mesh where covered, sky where allowed, the rest left out
                learn = ~m & sky_f[pix].to(device)
                sky = torch.nonzero(learn).flatten()
                sky_rgb, sky_aux = skybox(origins_t[view.to(device)].repeat_interleave(p * p, dim=0)[sky],
                                          dirs_b[sky, :3])
                full = torch.zeros(pix.numel(), 3, dtype=rgb.dtype, device=device).index_put(
                    (sel,), rgb).index_put((sky,), sky_rgb)
                m = m | learn
                sel = torch.nonzero(m).flatten()
                rgb = full[sel]
                vq_loss = vq_loss + sky_aux["vq_loss"] * (sky.numel() / max(whole.sky, 1))
            l2 = torch.sum((rgb - tgt[sel]) ** 2) / (3 * max(whole.learned, 1))   # the batch's mean
            loss = l2 + vq_weight * vq_loss
            if use_ssim:
                full = tgt.index_put((sel,), rgb)
                a = full.view(len(mine), p, p, 3).permute(0, 3, 1, 2)
                b = tgt.view(len(mine), p, p, 3).permute(0, 3, 1, 2)
                loss = loss + ssim_weight * (len(mine) / batch_patches) * (
                    1.0 - ssim(a, b, window=7, mask=m.view(len(mine), p, p)))

            opt_tex.zero_grad(set_to_none=True)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if exchange is not None:                  # sum the ranks' gradients; rank 0's clock, the batch's loss
                own_clock = time.perf_counter() - t0 if exchange.rank == 0 else 0.0
                shared_clock, l2_sum, loss_sum = exchange.reduce(
                    dense_params, sparse_params, [own_clock, float(l2.detach()), float(loss.detach())])
                l2, loss = torch.tensor(l2_sum), torch.tensor(loss_sum)
            opt_tex.step()
            opt.step()
            if exchange is not None and model.quantizing:   # dead codes restart from each rank's own samples
                exchange.agree([m_.vq.codebook.data for m_ in models])
            step += 1
            bar.update(1)

            if step % log_every == 0 or step == steps:
                l2v = float(l2.detach())
                entry = {"step": step, "seconds": time.perf_counter() - t0, "loss": float(loss.detach()),
                         "psnr": -10.0 * math.log10(max(l2v, 1e-10)), "lr": base_lrs[1][0] * decay}
                if model.quantizing:
                    entry.update(perplexity=model.vq.perplexity, used_fraction=model.vq.used_fraction)
                log.entries.append(entry)
                bar.set_postfix(psnr=f"{entry['psnr']:.2f}", loss=f"{entry['loss']:.4f}")
            if checkpoint is not None and step < steps and checkpoint.due():
                checkpoint.save(_snapshot(step, time.perf_counter() - t0, model, skybox, models, opt_tex, opt,
                                          gen, log))
    finally:
        bar.close()
        torch.set_num_threads(old_threads)
        log.seconds = time.perf_counter() - t0
        for m_ in models:
            m_.record_touched = False
    log.steps = step
    if exchange is not None:
        for m_ in models:
            exchange.union(m_.touched)
        if exchange.rank != 0:
            return log
    log.steps_per_second = (step - (log.resumed_from_step or 0)) / max(
        log.seconds - (float(stored["elapsed"]) if stored is not None else 0.0), 1e-9)
    log.processes = exchange.world if exchange is not None else 1
    log.pixels_per_second_per_process = log.steps_per_second * batch_patches * p * p / log.processes
    if checkpoint is not None:
        log.checkpoints_written = checkpoint.saved
    model.cpu()                    # the trained model leaves on the host (quantization and texel fill run there)
    if skybox is not None:
        skybox.cpu()
    if model.use_vq and not model.quantizing:      # quantize after training (or the warm-up outlasted the run)
        for m_ in models:
            m_.start_vq(after_training=True)
        log.vq_start_step = step if model.quantizing else None
    log.exact_codes = bool(model.vq_skipped)
    if model.quantizing:
        log.vq_stats = {**model.vq.stats(), **_texel_code_stats(model)}
    log.touched_fraction = float(model.touched.float().mean())
    log.filled_texels = model.fill_unseen_texels()
    model.eval()
    if skybox is not None:
        log.sky_touched_fraction = float(skybox.atlas.touched.float().mean())
        skybox.atlas.fill_unseen_texels()
        skybox.eval()
    return log


def _snapshot(step: int, elapsed: float, model, skybox, models, opt_tex, opt, gen, log: TrainLog) -> dict:
    """Everything the loop needs to go on from ``step`` (:class:`neural.train_checkpoint.TrainCheckpoint`)."""
    return {"step": step, "elapsed": elapsed, "model": model.state_dict(),
            "skybox": skybox.state_dict() if skybox is not None else None,
            "touched": [m.touched.clone() for m in models],
            "opt_tex": opt_tex.state_dict(), "opt": opt.state_dict(), "generator": gen.get_state(),
            "entries": list(log.entries), "stopped_by": log.stopped_by}


def _restore(state: dict, model, skybox, models, opt_tex, opt, gen, log: TrainLog) -> int:
    """Load a :func:`_snapshot` into the loop's objects; returns its step."""
    model.load_state_dict(state["model"])
    if skybox is not None:
        skybox.load_state_dict(state["skybox"])
    for m, touched in zip(models, state["touched"]):
        m.touched.copy_(touched)
    opt_tex.load_state_dict(state["opt_tex"])
    opt.load_state_dict(state["opt"])
    gen.set_state(state["generator"])
    log.entries = list(state["entries"])
    log.resumed_from_step = int(state["step"])
    return int(state["step"])


@dataclass
class _BatchCounts:
    """Pixels of a whole batch: covered by the mesh, learnt by the skybox, and learnt at all."""
    mesh: int
    sky: int
    learned: int

    @staticmethod
    def of(covered: torch.Tensor, sky_allowed: torch.Tensor | None) -> _BatchCounts:
        """covered, sky_allowed: (P,) bool over the batch's pixels (sky_allowed None: no skybox)."""
        mesh = int(covered.sum())
        sky = 0 if sky_allowed is None else int((~covered & sky_allowed).sum())
        return _BatchCounts(mesh, sky, mesh + sky)


def _start_vq(m: torch.nn.Module, exchange: GradientExchange | None) -> None:
    """Start quantization of ``m`` (a model or a skybox atlas) from the touched texels of every rank, with
    rank 0's k-means codebook on every rank."""
    if exchange is None:
        m.start_vq()
        return
    exchange.union(m.touched)
    m.start_vq()
    exchange.agree([m.vq.codebook.data])


@torch.no_grad()
def _texel_code_stats(model: NeuralTextureModel) -> dict:
    """Code usage over the trained (touched) texels: {"perplexity", "used_fraction"} of their assignments.

    This replaces the training-time usage EMA, which says nothing when quantization starts after training."""
    idx = model.trained_texel_codes()
    used = int(torch.unique(idx).numel())
    return {"perplexity": model.vq.perplexity_of(idx, model.vq.num_codes),
            "used_fraction": used / model.vq.num_codes}
