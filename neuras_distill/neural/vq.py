"""Vector quantization of texel features (VQ-VAE style, straight-through estimator).

Owns: :class:`VectorQuantizer`. Decisions (``docs/stability.md`` lists the cases that test them):

- Distances are computed in float32 on vectors centred by the codebook mean, in the expanded form
  ``|e_c|^2 - 2 x_c . e_c`` (the ``|x_c|^2`` term does not change the argmin). Centring keeps assignments
  right for codebooks far from the origin (offset 1e3, codes 0.01 apart).
- Forward value is exactly the code (``e.detach() + (z - z.detach())``: bit-exact ``e`` in the forward pass,
  identity gradient to ``z``), so what trains is bit-for-bit what the baked shader plays.
- Loss ``|sg[z] - e|^2 + beta |z - sg[e]|^2`` (means over elements); the codebook is a gradient-trained parameter.
- Usage is tracked per code as an EMA of assignment counts and as "steps since last used"; codes unused for
  ``dead_after`` training steps are replaced by random current inputs (dead-code reset) -- unless
  ``owned_codes`` (set by the model: a callable giving a (K,) bool mask of the codes some trained texel still
  maps to) says a texel outside the recent batches still uses them. Without that check a large scene lost its
  rare colours: a code for a car seen in few views went unused for 100 steps, was reset to a random (mostly
  grey) batch feature, and the car's texels fell onto grey codes (the street scene trained to a desaturated
  21-24 dB; the same atlas without VQ kept its colours).
- ``init_from(z)``: k-means++ seeding then k-means (10 Lloyd iterations, empty clusters keep their centre) on a
  sample of ``z``.
"""

from __future__ import annotations

import hashlib
import math

import torch
from torch import nn


def _content_digest(*tensors: torch.Tensor) -> bytes:
    """BLAKE2b of the tensors' dtypes, shapes and bytes (16 MB of features in ~20 ms)."""
    h = hashlib.blake2b(digest_size=16)
    for t in tensors:
        a = t.detach().float().contiguous().cpu()
        h.update(f"{a.dtype}{tuple(a.shape)}".encode())
        h.update(a.numpy().tobytes())
    return h.digest()


class VectorQuantizer(nn.Module):
    """Nearest-code quantizer with STE, codebook/commitment loss, usage stats and dead-code reset.

    Args:
        num_codes: K codes.
        dim: D, feature size.
        beta: commitment weight.
        dead_after: a code not chosen by any input for this many training forwards is reset (0 disables).
        usage_decay: EMA decay of the per-code usage counts (for stats).
    """

    def __init__(self, num_codes: int, dim: int, beta: float = 0.25, dead_after: int = 50,
                 usage_decay: float = 0.99) -> None:
        super().__init__()
        if num_codes < 1 or dim < 1:
            raise ValueError(f"VectorQuantizer needs num_codes >= 1 and dim >= 1, got {num_codes}, {dim}")
        self.num_codes, self.dim, self.beta = int(num_codes), int(dim), float(beta)
        self.dead_after, self.usage_decay = int(dead_after), float(usage_decay)
        self.codebook = nn.Parameter(torch.randn(self.num_codes, self.dim) * 1e-2)
        self.register_buffer("ema_usage", torch.zeros(self.num_codes))
        self.register_buffer("steps_unused", torch.zeros(self.num_codes, dtype=torch.long))
        self.register_buffer("initialized", torch.tensor(False))
        self.num_resets = 0
        self.owned_codes = None      # optional callable () -> (K,) bool: codes some texel still maps to
        self._steps = 0
        self._owned_mask, self._owned_at = None, None    # the mask is recomputed at most every dead_after steps
        self._all_codes = None       # (content digest of z and codebook, indices) of the last quantize_all

    # ------------------------------------------------------------------ assignment
    @torch.no_grad()
    def _nearest(self, z: torch.Tensor, codebook: torch.Tensor | None = None, block: int = 256) -> torch.Tensor:
        """(M, D) -> (M,) int64 index of the nearest code (Euclidean, fp32, centred).

        Rows go in blocks of ``block`` so the (block, K) distance tile stays in cache; one fused addmm
        (``|e_c|^2 - 2 x_c e_c^T``) per tile, then argmin.
        """
        e = (self.codebook if codebook is None else codebook).detach().float()
        mu = e.mean(dim=0, keepdim=True)
        ec = e - mu
        ect = ec.t().contiguous()
        e2 = (ec * ec).sum(dim=1)[None, :]
        xc = z.detach().float() - mu
        out = torch.empty(xc.shape[0], dtype=torch.long, device=xc.device)
        tile = torch.empty(min(block, max(xc.shape[0], 1)), e.shape[0], device=xc.device)
        for s in range(0, xc.shape[0], block):
            x = xc[s:s + block]
            t = tile[:x.shape[0]]
            torch.addmm(e2, x, ect, beta=1.0, alpha=-2.0, out=t)
            torch.argmin(t, dim=1, out=out[s:s + block])
        return out

    @torch.no_grad()
    def quantize_all(self, z: torch.Tensor, chunk: int = 65536) -> torch.Tensor:
        """Nearest-code indices of every row of z (M, D), computed in chunks -> (M,) int64.

        The last result is kept under a digest of the contents of z and the codebook: baking asks for the
        whole atlas more than once (the index texture, the plain-texture colours), and with 32768 codes over a
        704^2 atlas each pass costs ~12 s on two cores. A changed texel or code changes the digest."""
        key = _content_digest(z, self.codebook)
        if self._all_codes is not None and self._all_codes[0] == key:
            return self._all_codes[1].clone()
        out = torch.empty(z.shape[0], dtype=torch.long, device=z.device)
        for s in range(0, z.shape[0], chunk):
            out[s:s + chunk] = self._nearest(z[s:s + chunk])
        self._all_codes = (key, out.clone())
        return out

    # ------------------------------------------------------------------ forward
    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Quantize.

        Args:
            z: (M, D) features.
        Returns:
            z_q_st: (M, D) float32, forward value exactly ``codebook[indices]``, gradient identity to z.
            indices: (M,) int64.
            vq_loss: scalar, ``mse(e, sg[z]) + beta * mse(z, sg[e])``.
        """
        z = z.float()
        indices = self._nearest(z)
        e = self.codebook[indices]
        vq_loss = torch.mean((e - z.detach()) ** 2) + self.beta * torch.mean((z - e.detach()) ** 2)
        z_q_st = e.detach() + (z - z.detach())
        if self.training:
            self._update_usage(indices, z)
        return z_q_st, indices, vq_loss

    @torch.no_grad()
    def _update_usage(self, indices: torch.Tensor, z: torch.Tensor) -> None:
        counts = torch.bincount(indices, minlength=self.num_codes).float()
        self.ema_usage.mul_(self.usage_decay).add_(counts, alpha=1.0 - self.usage_decay)
        used = counts > 0
        self.steps_unused.add_(1)
        self.steps_unused[used] = 0
        self._steps += 1
        if self.dead_after > 0:
            dead = torch.nonzero(self.steps_unused >= self.dead_after).flatten()
            if dead.numel() > 0 and self.owned_codes is not None:
                if self._owned_at is None or self._steps - self._owned_at >= self.dead_after:
                    self._owned_mask, self._owned_at = self.owned_codes().to(dead.device), self._steps
                owned = self._owned_mask
                self.steps_unused[dead[owned[dead]]] = 0           # still used by texels outside recent batches
                dead = dead[~owned[dead]]
            if dead.numel() > 0 and z.shape[0] > 0:
                pick = torch.randint(0, z.shape[0], (dead.numel(),), device=z.device)
                self.codebook.data[dead] = z.detach()[pick].float()
                self.steps_unused[dead] = 0
                self.ema_usage[dead] = self.ema_usage.mean()
                self.num_resets += int(dead.numel())

    # ------------------------------------------------------------------ init
    @torch.no_grad()
    def init_from(self, z: torch.Tensor, iters: int = 10, max_samples: int = 65536,
                  generator: torch.Generator | None = None) -> None:
        """k-means initialisation of the codebook from z (M, D) (a random sample of at most max_samples rows).

        Seeds with k-means++ on at most 16*K rows (when M < K: every row its own code, the K - M others copies of
        random rows with a tiny jitter, so that every texel keeps its own value: drawing all K with replacement
        left 444 of 1000 texels sharing a code with 1024 codes), then ``iters`` Lloyd iterations; empty clusters
        keep their previous centre. Runs on the host whatever the codebook's device (the generator is a host one:
        the same codes on every device).
        """
        z = z.detach().float().cpu()
        if z.shape[0] == 0:
            raise ValueError("init_from needs at least one vector")
        if z.shape[0] > max_samples:
            z = z[torch.randperm(z.shape[0], generator=generator)[:max_samples]]
        m, k = z.shape[0], self.num_codes
        if m >= k:
            centres = self._kmeans_pp(z[torch.randperm(m, generator=generator)[:16 * k]], k, generator)
        else:
            centres = torch.cat([z, z[torch.randint(0, m, (k - m,), generator=generator)]])
            scale = z.std(dim=0, keepdim=True).clamp_min(1e-6) * 1e-3
            centres[m:] += torch.randn(k - m, z.shape[1], generator=generator) * scale
        for _ in range(iters):
            assign = self._nearest(z, centres)
            sums = torch.zeros_like(centres).index_add_(0, assign, z)
            counts = torch.bincount(assign, minlength=k).float()
            nonempty = counts > 0
            centres[nonempty] = sums[nonempty] / counts[nonempty, None]
        self.codebook.data.copy_(centres)
        self.ema_usage.fill_(0.0)
        self.steps_unused.zero_()
        self._owned_mask, self._owned_at = None, None
        self.initialized.fill_(True)

    @staticmethod
    def _kmeans_pp(z: torch.Tensor, k: int, generator: torch.Generator | None, rounds: int = 64) -> torch.Tensor:
        """k-means++ seeding in ``rounds`` batches: k rows of z (M >= k, D). Each round draws its share of the
        remaining centres at once, without replacement, with probability ~ squared distance to the centres
        chosen so far (one-at-a-time seeding took 15 s for 4096 codes and 28 s for 8192 on 64k rows, two CPU
        cores; batched it takes well under a second, and the Lloyd iterations that follow even out the
        difference)."""
        centres = torch.empty(k, z.shape[1], dtype=z.dtype)
        first = int(torch.randint(0, z.shape[0], (1,), generator=generator))
        centres[0] = z[first]
        d2 = ((z - centres[0]) ** 2).sum(1)
        done, rounds = 1, max(1, min(int(rounds), k - 1))
        for r in range(rounds):
            take = min(k - done, -(-(k - done) // (rounds - r)))       # ceil: the rest spread over the rounds left
            if take <= 0:
                break
            positive = int((d2 > 0).sum())
            if positive >= take:
                picks = torch.multinomial(d2 / d2.sum(), take, replacement=False, generator=generator)
            else:                                  # fewer distinct rows than codes left: any rows will do
                picks = torch.randint(0, z.shape[0], (take,), generator=generator)
            centres[done:done + take] = z[picks]
            for lo in range(0, take, 1024):
                new = z[picks[lo:lo + 1024]]
                d2 = torch.minimum(d2, torch.cdist(z, new).pow(2).min(dim=1).values)
            done += take
        return centres

    # ------------------------------------------------------------------ stats and baking
    @staticmethod
    def perplexity_of(indices: torch.Tensor, num_codes: int) -> float:
        """exp(entropy) of the code histogram of ``indices`` (1 = one code used, K = uniform use)."""
        counts = torch.bincount(indices.flatten(), minlength=num_codes).double()
        p = counts / counts.sum().clamp_min(1.0)
        p = p[p > 0]
        return float(torch.exp(-(p * p.log()).sum()))

    @property
    def perplexity(self) -> float:
        """exp(entropy) of the EMA usage distribution."""
        total = float(self.ema_usage.sum())
        if total <= 0:
            return 0.0
        p = (self.ema_usage.double() / total)
        p = p[p > 0]
        return float(math.exp(-float((p * p.log()).sum())))

    @property
    def used_fraction(self) -> float:
        """Fraction of codes chosen at least once within the last ``dead_after`` (or 100) training forwards."""
        window = self.dead_after if self.dead_after > 0 else 100
        return float((self.steps_unused < window).float().mean())

    def stats(self) -> dict:
        return {"perplexity": self.perplexity, "used_fraction": self.used_fraction,
                "num_codes": self.num_codes, "dead_code_resets": self.num_resets}

    @torch.no_grad()
    def prune(self, used_indices: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Drop codes that ``used_indices`` never references.

        Args:
            used_indices: int64 tensor of any shape with values in [0, K).
        Returns:
            codebook: (K', D) float32 copy of the used codes, in increasing old-index order.
            remap: (K,) int64, new index of each old code, -1 for dropped codes
                (``remap[used_indices]`` indexes the pruned codebook).
        """
        used = torch.zeros(self.num_codes, dtype=torch.bool, device=used_indices.device)
        used[used_indices.flatten()] = True
        keep = torch.nonzero(used).flatten()
        remap = torch.full((self.num_codes,), -1, dtype=torch.long, device=used_indices.device)
        remap[keep] = torch.arange(keep.numel(), device=used_indices.device)
        return self.codebook.detach()[keep].float().clone(), remap

    def extra_repr(self) -> str:
        return f"num_codes={self.num_codes}, dim={self.dim}, beta={self.beta}, dead_after={self.dead_after}"
