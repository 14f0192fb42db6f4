"""Stopping training when it stops paying: a held-back set of training pixels, scored now and then.

Owns: :class:`PlateauStop`. A fixed share of the training pixels (every ``hold_back_every``-th of the pixels a
step may learn, after a seeded shuffle) is left out of the loss. Every ``check_every`` steps the model (and the
skybox) colours them, and their PSNR against the teacher is recorded. Training stops on a plateau: once the run
is past ``min_progress`` of its planned steps, when the best held-back PSNR of the last ``patience`` checks is
less than ``min_gain_db`` above the best before them. The pixels are scored with continuous features (the codes
are fitted after training), in the training device's arithmetic.
"""

from __future__ import annotations

import math

import torch

from neuras_distill.neural.train_batches import PixelRows


class PlateauStop:
    """The plateau rule of one run (see the module docstring). ``history``: [(step, held-back PSNR in dB)]."""

    def __init__(self, hold_back_every: int = 64, check_every: int = 100, patience: int = 4,
                 min_gain_db: float = 0.05, min_progress: float = 0.5, max_pixels: int = 16384, seed: int = 0):
        self.hold_back_every, self.check_every, self.patience = int(hold_back_every), int(check_every), int(patience)
        self.min_gain_db, self.min_progress, self.max_pixels, self.seed = float(min_gain_db), float(min_progress), \
            int(max_pixels), int(seed)
        self.held: torch.Tensor | None = None
        self.history: list[tuple[int, float]] = []

    def hold_back(self, pixels: PixelRows) -> None:
        """Take the held-back pixels out of ``pixels`` (in place): out of the loss (``covered`` and the sky's
        ``allowed`` set to False) and off the patch centres. At most ``max_pixels`` are kept for scoring."""
        learnt = pixels.covered if pixels.sky is None else pixels.covered | pixels.sky.allowed
        candidates = torch.nonzero(learnt).flatten()
        gen = torch.Generator().manual_seed(self.seed + 7919)
        order = candidates[torch.randperm(candidates.numel(), generator=gen)]
        self.held = torch.sort(order[::self.hold_back_every][:self.max_pixels]).values
        self.on_mesh = pixels.covered[self.held].clone()      # the others are the skybox's
        pixels.covered = pixels.covered.clone()                # the caller's arrays (memory-mapped) stay as they are
        pixels.covered[self.held] = False
        if pixels.sky is not None:
            pixels.sky.allowed = pixels.sky.allowed.clone()
            pixels.sky.allowed[self.held] = False
        keep = torch.ones(pixels.covered.numel(), dtype=torch.bool)
        keep[self.held] = False
        pixels.centres = pixels.centres[keep[pixels.centres]]

    @torch.no_grad()
    def psnr(self, model, skybox, pixels: PixelRows, models: list) -> float:
        """PSNR in dB of the model's (and skybox's) colours of the held-back pixels against the teacher's, in eval
        mode; ``models`` (the modules recording touched texels) record nothing meanwhile."""
        device = model.texture.data.device
        for m in models:
            m.record_touched = False
        for m in (model, skybox):                      # no quantizer statistics or code restarts from scoring
            if m is not None:
                m.eval()
        idx, mesh = self.held, self.on_mesh
        rgb = torch.zeros(idx.numel(), 3, device=device)
        if mesh.any():
            sel = idx[mesh]
            rgb[mesh.to(device)] = model(pixels.uv[sel].to(device), pixels.dirs[sel].to(device))[0]
        if skybox is not None and (~mesh).any():
            sel = idx[~mesh]
            view = torch.div(sel, pixels.lead[1] * pixels.lead[2], rounding_mode="floor")
            rgb[(~mesh).to(device)] = skybox(pixels.sky.origins[view.to(device)], pixels.dirs[sel, :3].to(device))[0]
        for m in models:
            m.record_touched = True
        for m in (model, skybox):
            if m is not None:
                m.train()
        mse = float(torch.mean((rgb.cpu() - pixels.targets[idx]) ** 2))
        return -10.0 * math.log10(max(mse, 1e-10))

    def plateau(self, step: int, steps: int, model, skybox, pixels: PixelRows, models: list) -> bool:
        """At every ``check_every``-th step: score the held-back pixels (:meth:`psnr`) and :meth:`record` it;
        True when training should stop."""
        if self.held is None or self.held.numel() == 0 or step % self.check_every:
            return False
        return self.record(step, self.psnr(model, skybox, pixels, models), steps)

    def record(self, step: int, psnr: float, steps: int) -> bool:
        """Record the held-back PSNR at ``step`` of ``steps``; True when training should stop (a plateau)."""
        self.history.append((int(step), float(psnr)))
        if step < self.min_progress * steps or len(self.history) <= self.patience:
            return False
        before = max(p for _, p in self.history[:-self.patience])
        recent = max(p for _, p in self.history[-self.patience:])
        return recent < before + self.min_gain_db
