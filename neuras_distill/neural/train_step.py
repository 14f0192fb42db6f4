"""One optimisation step of :func:`neuras_distill.neural.train.fit`: the loss of a batch and the optimisers.

Owns: :class:`BatchLoss` (the mesh's pixels through the model, the skybox's through the skybox, L2 + VQ + SSIM
terms normalised by the whole batch's counts) and :class:`Optimisers` (sparse Adam on the atlases, Adam on the
MLPs and codebooks, the learning-rate decay).

Loss: ``L2 on the learnt pixels + vq_weight * vq_loss + ssim_weight * (1 - SSIM)``. For SSIM the pixels not
learnt are set to the target, and the SSIM map is averaged over learnt window centres. With a data-parallel
exchange each rank computes its share of the patches; its terms are divided by the whole batch's counts, so the
ranks' gradients sum to the one-process gradient.
"""

from __future__ import annotations

import torch

from neuras_distill.config import TrainConfig
from neuras_distill.neural.losses import ssim
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.train_batches import PixelRows

#: Weight of the quantizer's commitment / codebook loss while training under quantization.
VQ_WEIGHT = 1.0
#: The learning rates decay exponentially to this multiple of their start over the run.
LR_FINAL_RATIO = 0.1


class BatchLoss:
    """The loss of one batch for ``model`` (and ``skybox``) on ``pixels``, computed on ``device``."""

    def __init__(self, model: NeuralTextureModel, skybox, pixels: PixelRows, config: TrainConfig,
                 device: torch.device, exchange=None) -> None:
        self.model, self.skybox, self.pixels, self.device, self.exchange = model, skybox, pixels, device, exchange
        self.batch_patches = config.batch_patches
        self.p = pixels.patch_side(config.patch)
        self.ssim_weight = config.ssim_weight
        self.use_ssim = config.ssim_weight > 0 and self.p >= 7

    def __call__(self, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """(l2, loss) scalar tensors of the batch drawn with ``gen``: this rank's share of the whole batch's mean
        L2 over learnt pixels, and of the whole loss."""
        px, p, device = self.pixels, self.p, self.device
        pix, view = px.draw(gen, self.batch_patches, p)
        whole = px.counts(pix)             # counts of the whole batch (every rank's share)
        mine = self.exchange.share(self.batch_patches) if self.exchange is not None else torch.arange(self.batch_patches)
        pix, view = pix[mine].reshape(-1), view[mine]
        m, tgt = px.covered[pix].to(device), px.targets[pix].to(device)
        uv_b, dirs_b = px.uv[pix].to(device), px.dirs[pix].to(device)
        sel = torch.nonzero(m).flatten()
        rgb, aux = self.model(uv_b[sel], dirs_b[sel])
        vq_loss = aux["vq_loss"] * (sel.numel() / max(whole.mesh, 1))
        if self.skybox is not None:        # mesh where covered, sky where allowed, the rest left out
            learn = ~m & px.sky.allowed[pix].to(device)
            sky = torch.nonzero(learn).flatten()
            sky_rgb, sky_aux = self.skybox(px.sky.origins[view.to(device)].repeat_interleave(p * p, dim=0)[sky],
                                           dirs_b[sky, :3])
            full = torch.zeros(pix.numel(), 3, dtype=rgb.dtype, device=device).index_put(
                (sel,), rgb).index_put((sky,), sky_rgb)
            m = m | learn
            sel = torch.nonzero(m).flatten()
            rgb = full[sel]
            vq_loss = vq_loss + sky_aux["vq_loss"] * (sky.numel() / max(whole.sky, 1))
        l2 = torch.sum((rgb - tgt[sel]) ** 2) / (3 * max(whole.learned, 1))   # the batch's mean
        loss = l2 + VQ_WEIGHT * vq_loss
        if self.use_ssim:
            full = tgt.index_put((sel,), rgb)
            a = full.view(len(mine), p, p, 3).permute(0, 3, 1, 2)
            b = tgt.view(len(mine), p, p, 3).permute(0, 3, 1, 2)
            loss = loss + self.ssim_weight * (len(mine) / self.batch_patches) * (
                1.0 - ssim(a, b, window=7, mask=m.view(len(mine), p, p)))
        return l2, loss


class Optimisers:
    """The atlases (the mesh's and the skybox's) under ``SparseAdam`` on sparse gradients (a step costs O(batch),
    not O(atlas); plain Adam when the model's gradients are dense) at ``texture_lr_scale * lr``, the atlas's
    coarse level (dense gradients) under Adam at the same rate; the MLPs and codebooks under Adam at ``lr``.
    ``sparse`` and ``dense`` list the parameters by the kind of their gradient."""

    def __init__(self, model: NeuralTextureModel, skybox, config: TrainConfig) -> None:
        tex_params = [model.texture.data]
        texture_lr = config.texture_lr_scale * config.lr
        dense_groups = [{"params": list(model.shaders.parameters()), "lr": config.lr}]
        if model.texture.coarse is not None:       # small, and its gradient is dense
            dense_groups.append({"params": [model.texture.coarse], "lr": texture_lr})
        if model.vq is not None:
            dense_groups.append({"params": [model.vq.codebook], "lr": config.lr})
        if skybox is not None:
            tex_params.append(skybox.atlas.texture.data)
            dense_groups.append({"params": skybox.dense_parameters(), "lr": config.lr})
        self.texture = (torch.optim.SparseAdam(tex_params, lr=texture_lr) if model.sparse_grad
                        else torch.optim.Adam(tex_params, lr=texture_lr))
        self.mlp = torch.optim.Adam(dense_groups)
        self.base_lrs = [[g["lr"] for g in o.param_groups] for o in (self.texture, self.mlp)]
        self.sparse = tex_params if model.sparse_grad else []
        self.dense = [q for g in dense_groups for q in g["params"]] + ([] if model.sparse_grad else tex_params)

    def decay(self, frac: float) -> float:
        """Set every learning rate to its start times ``LR_FINAL_RATIO ** min(frac, 1)`` (``frac``: the run's
        progress, 0..1); returns that factor."""
        decay = LR_FINAL_RATIO ** min(frac, 1.0)
        for o, bases in zip((self.texture, self.mlp), self.base_lrs):
            for g, b in zip(o.param_groups, bases):
                g["lr"] = b * decay
        return decay

    def mlp_lr(self, decay: float) -> float:
        """The MLP's learning rate at ``decay`` (what the log reports)."""
        return self.base_lrs[1][0] * decay

    def zero_grad(self) -> None:
        self.texture.zero_grad(set_to_none=True)
        self.mlp.zero_grad(set_to_none=True)

    def step(self) -> None:
        self.texture.step()
        self.mlp.step()

    def state_dict(self) -> dict:
        return {"opt_tex": self.texture.state_dict(), "opt": self.mlp.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.texture.load_state_dict(state["opt_tex"])
        self.mlp.load_state_dict(state["opt"])
