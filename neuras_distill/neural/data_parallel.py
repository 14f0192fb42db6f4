"""Gradient exchange between the ranks of a data-parallel :func:`neuras_distill.neural.train.fit`.

Owns: :class:`GradientExchange` (torch.distributed collectives; gloo on the CPU).

How the ranks stay one model:
- Every rank holds the same model and the same training arrays, and draws the same batch of patches from a
  generator with the same seed; rank ``r`` computes patches ``r, r + world, ...`` (:meth:`GradientExchange.share`).
- Each rank's loss terms are normalised by the whole batch's counts (covered pixels, sky pixels, patches), so
  the ranks' gradients sum to the one-process gradient of the whole batch.
- :meth:`GradientExchange.reduce` sums them: the dense gradients (MLPs, codebook) flattened into one
  ``all_reduce``; each sparse atlas gradient (a COO tensor of the touched texels, lazy Adam's input) by
  ``all_gather`` of its rows (indices and values, padded to the largest rank's count), concatenated into one
  uncoalesced COO tensor: the sum, sending O(batch) instead of O(atlas). Every rank then takes the same optimiser
  step, so the models agree up to the order of float additions.
- Decisions that must agree (stop on the time budget, the learning-rate decay, quantization start) use rank 0's
  clock, carried in the same ``all_reduce`` one step late.
- :meth:`GradientExchange.union` ORs the ranks' touched-texel masks at the end (and before k-means when
  quantization starts during training); :meth:`GradientExchange.agree` gives every rank rank 0's codebook after
  k-means and after each quantized step (dead codes restart from each rank's own samples).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class GradientExchange:
    """This process's place in a data-parallel fit: ``rank`` of ``world`` processes in torch.distributed's
    default group (already initialised)."""

    rank: int
    world: int

    def share(self, count: int) -> torch.Tensor:
        """(count // world or one more,) int64: the items of a batch of ``count`` that this rank computes."""
        return torch.arange(self.rank, count, self.world)

    def reduce(self, dense: list[torch.Tensor], sparse: list[torch.Tensor], extras: list[float]) -> list[float]:
        """Sum every parameter's gradient over the ranks, in place (``.grad`` of each tensor in ``dense`` and
        ``sparse``; a missing one counts as zero), and the floats ``extras`` (returned summed; float32, so a clock in
        seconds keeps ~1 ms over hours)."""
        import torch.distributed as dist

        flat = [p.grad.reshape(-1) if p.grad is not None else torch.zeros(p.numel(), dtype=p.dtype)
                for p in dense]
        present = [float(p.grad is not None) for p in dense]      # Adam skips a parameter without a gradient
        buf = torch.cat(flat + [torch.tensor(present + list(extras), dtype=torch.float32)])   # one collective
        dist.all_reduce(buf)
        start = 0
        tail = buf[sum(p.numel() for p in dense):]
        for k, p in enumerate(dense):
            n = p.numel()
            if float(tail[k]) == 0.0:
                p.grad = None
            elif p.grad is None:
                p.grad = buf[start:start + n].view_as(p).clone()
            else:
                p.grad.copy_(buf[start:start + n].view_as(p))
            start += n
        for p in sparse:
            p.grad = self._gather_sparse(p)
        return tail[len(dense):].tolist()

    def _gather_sparse(self, p: torch.Tensor) -> torch.Tensor:
        """The sum over ranks of ``p``'s sparse COO gradient (sparse dims first, one dense trailing dim)."""
        import torch.distributed as dist

        g = p.grad
        sparse_dims = p.dim() - 1
        if g is None:
            idx = torch.zeros(sparse_dims, 0, dtype=torch.int64)
            val = torch.zeros(0, p.shape[-1], dtype=p.dtype)
        else:
            idx, val = g._indices(), g._values()
        counts = [torch.zeros(1, dtype=torch.int64) for _ in range(self.world)]
        dist.all_gather(counts, torch.tensor([idx.shape[1]], dtype=torch.int64))
        most = int(max(int(c) for c in counts))
        pad = most - idx.shape[1]
        idx_p = torch.cat([idx, torch.zeros(sparse_dims, pad, dtype=torch.int64)], dim=1)
        val_p = torch.cat([val, torch.zeros(pad, val.shape[1], dtype=val.dtype)], dim=0)
        all_idx = [torch.empty_like(idx_p) for _ in range(self.world)]
        all_val = [torch.empty_like(val_p) for _ in range(self.world)]
        dist.all_gather(all_idx, idx_p.contiguous())
        dist.all_gather(all_val, val_p.contiguous())
        idx_cat = torch.cat([a[:, :int(c)] for a, c in zip(all_idx, counts)], dim=1)
        val_cat = torch.cat([v[:int(c)] for v, c in zip(all_val, counts)], dim=0)
        return torch.sparse_coo_tensor(idx_cat, val_cat, tuple(p.shape), check_invariants=False)

    def union(self, mask: torch.Tensor) -> None:
        """OR a bool mask over the ranks, in place."""
        import torch.distributed as dist

        as_bytes = mask.to(torch.uint8)
        dist.all_reduce(as_bytes, op=dist.ReduceOp.MAX)
        mask.copy_(as_bytes.bool())

    def agree(self, tensors: list[torch.Tensor]) -> None:
        """Overwrite ``tensors`` with rank 0's values (a codebook after k-means or dead-code restarts, which draw
        from each rank's own samples)."""
        import torch.distributed as dist

        for t in tensors:
            dist.broadcast(t, src=0)
