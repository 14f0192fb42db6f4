"""Fitting a :class:`NeuralTextureModel` to teacher images through rasterized G-buffers.

Owns: :func:`fit` (the loop) and :class:`TrainLog`. The loop calls its parts: ``train_batches`` (the pixels and
the patches drawn from them), ``train_step`` (a batch's loss, the skybox's share of it, the optimisers) and, with
several processes, ``data_parallel.GradientExchange``.

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
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch
from tqdm import tqdm

from neuras_distill.config import TrainConfig
from neuras_distill.errors import BadInputError, require
from neuras_distill.neural.convergence import PlateauStop
from neuras_distill.neural.data_parallel import GradientExchange
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.train_batches import PixelRows, TrainingPixels
from neuras_distill.neural.train_step import BatchLoss, Optimisers

#: The library's defaults are the configuration's (one place: ``config.py``).
_TRAIN = TrainConfig()


@dataclass
class TrainLog:
    """What ``fit`` did.

    Attributes:
        entries: [{"step", "seconds", "loss", "psnr" (batch, covered pixels), "lr", and when quantizing
            "perplexity", "used_fraction"}] at every ``log_every`` steps and at the last step.
        steps: optimisation steps done; seconds: wall time of the loop; steps_per_second.
        stopped_by: "steps", "time_budget" or "plateau" (``stop``); held_back: [[step, PSNR in dB]] of the held-back
            pixels at each check of ``stop``.
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
    held_back: list = field(default_factory=list)
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


def fit(model: NeuralTextureModel, views: TrainingPixels, *, steps: int, config: TrainConfig = _TRAIN,
        time_budget_s: float | None = None, skybox=None, checkpoint=None, device: torch.device | str | None = None,
        exchange: GradientExchange | None = None, progress=True, log_every: int | None = None,
        num_threads: int | None = None, stop: PlateauStop | None = None) -> TrainLog:
    """Train ``model`` on teacher images.

    Args:
        views: the :class:`~neuras_distill.neural.train_batches.TrainingPixels` learnt from: per view the uv,
            coverage, view inputs (unit directions, the facing cosine when the shader uses it, the mesh layer with
            two layers: ``neural.model.view_inputs``) and teacher colours; with a ``skybox``, the camera centres
            relative to ``skybox.layers.center`` (required) and the uncovered pixels it learns from
            (``pipeline.rules.near_miss_pixels``: the field shows a surface there that the mesh missed, which the
            skybox must not smear over the sky).
        steps: maximum optimisation steps; time_budget_s: optional wall-clock limit (whichever comes first).
        config: the :class:`TrainConfig` section (lr, texture_lr_scale, batch_patches, patch, ssim_weight,
            vq_warmup, seed; the rest is the pipeline's).
        skybox: optional :class:`SkyboxModel` trained jointly on the pixels the mesh does not cover.
        checkpoint: optional :class:`neural.train_checkpoint.TrainCheckpoint`: the loop starts from its stored
            state when it has one (``TrainLog.resumed_from_step``) and saves its state when it is due.
        device: where the model (and skybox) train (None: where the model is); the arrays stay in host memory.
        exchange: this process's :class:`~neuras_distill.neural.data_parallel.GradientExchange` when ``fit`` runs
            on several ranks at once (same model, arrays and seed): each computes its share of every batch.
        progress: True draws this loop's own bar, False nothing; a callable ``(step, steps)`` is called after every
            step instead (a run's display: ``pipeline/progress.py``).
        log_every: steps between log entries (default steps // 50); num_threads: torch intra-op threads during
            the loop (None: torch's setting; on a busy CPU 1 avoids OpenMP oversubscription: 108 vs 1.8 steps/s).
        stop: optional :class:`~neuras_distill.neural.convergence.PlateauStop` (one process only): its pixels are
            held back, and training stops when they stop improving (``TrainLog.stopped_by`` "plateau").
    Returns:
        :class:`TrainLog`. The model (and skybox) is left on the host in eval mode with untouched texels filled
        (on rank 0; the other ranks of an ``exchange`` return right after the loop, their model unquantized).
    """
    if steps < 1:
        raise BadInputError(f"fit: steps must be >= 1, got {steps}")
    pixels = views.rows(model.view_columns, skybox is not None)
    device = torch.device(device) if device is not None else model.texture.data.device
    models = _place(model, skybox, pixels, device, stop, exchange)
    batch_loss, opts = BatchLoss(model, skybox, pixels, config, device, exchange), Optimisers(model, skybox, config)
    gen = torch.Generator().manual_seed(config.seed)
    log_every = max(1, steps // 50) if log_every is None else max(1, int(log_every))
    log, clock = TrainLog(held_back=stop.history if stop is not None else []), _Clock(exchange)
    stored = checkpoint.load() if checkpoint is not None else None
    step = 0 if stored is None else _restore(stored, model, skybox, models, opts, gen, log, clock)
    report = progress if callable(progress) else None       # a run's own display (pipeline/progress.py)
    own_bar = bool(progress) and report is None
    with _threads(num_threads), tqdm(total=steps, initial=step, file=sys.stderr, disable=not own_bar,
                                     desc="distill", leave=False) as bar:
        try:
            while step < steps:
                frac = _progress(step, steps, clock.elapsed(), time_budget_s)
                if frac is None:
                    log.stopped_by = "time_budget"
                    break
                if model.use_vq and not model.quantizing and config.vq_warmup < 1.0 and frac >= config.vq_warmup:
                    log.vq_start_step = _start_vq(models, exchange, step)
                decay = opts.decay(frac)
                l2, loss = batch_loss(gen)
                opts.zero_grad()
                loss.backward()
                if exchange is not None:           # sum the ranks' gradients; rank 0's clock, the batch's loss
                    l2, loss = clock.reduce(opts, l2, loss)
                opts.step()
                if exchange is not None and model.quantizing:   # dead codes restart from each rank's own samples
                    exchange.agree([m_.vq.codebook.data for m_ in models])
                step += 1
                bar.update(1)
                if report is not None:
                    report(step, steps)
                if step % log_every == 0 or step == steps:
                    _log_step(log, bar, model, step, clock, l2, loss, opts.mlp_lr(decay))
                if stop is not None and stop.plateau(step, steps, model, skybox, pixels, models):
                    log.stopped_by = "plateau"
                    break
                if checkpoint is not None and step < steps and checkpoint.due():
                    checkpoint.save(_snapshot(step, clock.since_start(), model, skybox, models, opts, gen, log))
        finally:
            log.seconds, log.steps = clock.since_start(), step
            for m_ in models:
                m_.record_touched = False
    if exchange is not None and not _gather_touched(models, exchange):
        return log                                 # ranks other than 0 end here
    _finish(log, model, skybox, models, clock, config, pixels, exchange, checkpoint)
    return log


@contextmanager
def _threads(num_threads: int | None):
    """torch's intra-op threads set to ``num_threads`` (None: left alone) inside, restored after."""
    old = torch.get_num_threads()
    if num_threads is not None:
        torch.set_num_threads(int(num_threads))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _gather_touched(models: list, exchange: GradientExchange) -> bool:
    """OR every rank's touched texels into each of ``models``; True on rank 0."""
    for m_ in models:
        exchange.union(m_.touched)
    return exchange.rank == 0


def _place(model: NeuralTextureModel, skybox, pixels: PixelRows, device: torch.device,
           stop: PlateauStop | None, exchange: GradientExchange | None) -> list:
    """Move the model (and skybox, and the camera centres) to ``device`` in training mode, recording touched
    texels, and hold back ``stop``'s pixels; returns the modules with an atlas: [model] or [model, skybox.atlas]."""
    if stop is not None:
        require(exchange is None, "fit: the plateau stop runs in one process (with --nproc, configure --steps)")
        stop.hold_back(pixels)
    model.to(device)
    models = [model]
    if skybox is not None:
        skybox.to(device)
        pixels.sky.origins = pixels.sky.origins.to(device)
        models.append(skybox.atlas)
    model.train()
    if skybox is not None:
        skybox.train()
    for m_ in models:
        m_.record_touched = True
    return models


class _Clock:
    """The loop's wall clock: this process's, or rank 0's (carried one step late) for every rank of an exchange,
    so decisions that hang on time agree."""

    def __init__(self, exchange: GradientExchange | None) -> None:
        self.exchange = exchange
        self.t0 = time.perf_counter()
        self.shared = 0.0
        self.resumed = 0.0

    def resume(self, elapsed: float) -> None:
        """Go on from a checkpoint taken ``elapsed`` seconds into the run."""
        self.t0 -= elapsed
        self.shared = self.resumed = elapsed

    def since_start(self) -> float:
        return time.perf_counter() - self.t0

    def elapsed(self) -> float:
        """Seconds into the run as every rank sees them."""
        return self.since_start() if self.exchange is None else self.shared

    def reduce(self, opts: Optimisers, l2: torch.Tensor, loss: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Sum the ranks' gradients and losses, and take rank 0's clock; returns the whole batch's (l2, loss)."""
        own = self.since_start() if self.exchange.rank == 0 else 0.0
        self.shared, l2_sum, loss_sum = self.exchange.reduce(opts.dense, opts.sparse,
                                                             [own, float(l2.detach()), float(loss.detach())])
        return torch.tensor(l2_sum), torch.tensor(loss_sum)


def _progress(step: int, steps: int, elapsed: float, time_budget_s: float | None) -> float | None:
    """The run's progress 0..1 (the larger of steps and budget spent), or None when the time budget is spent."""
    frac = step / steps
    if time_budget_s is not None:
        if elapsed >= time_budget_s:
            return None
        frac = max(frac, elapsed / time_budget_s)
    return frac


def _log_step(log: TrainLog, bar, model: NeuralTextureModel, step: int, clock: _Clock, l2: torch.Tensor,
              loss: torch.Tensor, lr: float) -> None:
    """Append the step's entry to ``log.entries`` and show it on the progress bar."""
    l2v = float(l2.detach())
    entry = {"step": step, "seconds": clock.since_start(), "loss": float(loss.detach()),
             "psnr": -10.0 * math.log10(max(l2v, 1e-10)), "lr": lr}
    if model.quantizing:
        entry.update(perplexity=model.vq.perplexity, used_fraction=model.vq.used_fraction)
    log.entries.append(entry)
    bar.set_postfix(psnr=f"{entry['psnr']:.2f}", loss=f"{entry['loss']:.4f}")


def _finish(log: TrainLog, model: NeuralTextureModel, skybox, models: list, clock: _Clock, config: TrainConfig,
            pixels: PixelRows, exchange: GradientExchange | None, checkpoint) -> None:
    """After the loop, on rank 0: the log's speed figures; the model (and skybox) back on the host, quantized
    when it was not yet, untouched texels filled, in eval mode."""
    log.steps_per_second = (log.steps - (log.resumed_from_step or 0)) / max(log.seconds - clock.resumed, 1e-9)
    log.processes = exchange.world if exchange is not None else 1
    p = pixels.patch_side(config.patch)
    log.pixels_per_second_per_process = log.steps_per_second * config.batch_patches * p * p / log.processes
    if checkpoint is not None:
        log.checkpoints_written = checkpoint.saved
    model.cpu()                    # the trained model leaves on the host (quantization and texel fill run there)
    if skybox is not None:
        skybox.cpu()
    if model.use_vq and not model.quantizing:      # quantize after training (or the warm-up outlasted the run)
        for m_ in models:
            m_.start_vq(after_training=True)
        log.vq_start_step = log.steps if model.quantizing else None
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


def _snapshot(step: int, elapsed: float, model, skybox, models, opts: Optimisers, gen, log: TrainLog) -> dict:
    """Everything the loop needs to go on from ``step`` (:class:`neural.train_checkpoint.TrainCheckpoint`)."""
    return {"step": step, "elapsed": elapsed, "model": model.state_dict(),
            "skybox": skybox.state_dict() if skybox is not None else None,
            "touched": [m.touched.clone() for m in models], **opts.state_dict(), "generator": gen.get_state(),
            "entries": list(log.entries), "stopped_by": log.stopped_by, "held_back": list(log.held_back)}


def _restore(state: dict, model, skybox, models, opts: Optimisers, gen, log: TrainLog, clock: _Clock) -> int:
    """Load a :func:`_snapshot` into the loop's objects and clock; returns its step."""
    model.load_state_dict(state["model"])
    if skybox is not None:
        skybox.load_state_dict(state["skybox"])
    for m, touched in zip(models, state["touched"]):
        m.touched.copy_(touched)
    opts.load_state_dict(state)
    gen.set_state(state["generator"])
    log.entries = list(state["entries"])
    log.held_back[:] = [tuple(h) for h in state.get("held_back", [])]     # the plateau stop's own history
    log.resumed_from_step = int(state["step"])
    clock.resume(float(state["elapsed"]))
    return int(state["step"])


def _start_vq(models: list, exchange: GradientExchange | None, step: int) -> int:
    """Start quantization of each of ``models`` (the model, a skybox atlas) from the touched texels of every rank,
    with rank 0's k-means codebook on every rank; returns ``step``."""
    for m in models:
        if exchange is not None:
            exchange.union(m.touched)
        m.start_vq()
        if exchange is not None:
            exchange.agree([m.vq.codebook.data])
    return step


@torch.no_grad()
def _texel_code_stats(model: NeuralTextureModel) -> dict:
    """Code usage over the trained (touched) texels: {"perplexity", "used_fraction"} of their assignments.

    This replaces the training-time usage EMA, which says nothing when quantization starts after training."""
    idx = model.trained_texel_codes()
    used = int(torch.unique(idx).numel())
    return {"perplexity": model.vq.perplexity_of(idx, model.vq.num_codes),
            "used_fraction": used / model.vq.num_codes}
