"""Image losses for distillation: L2, an SSIM term (own implementation) and an optional VGG16 perceptual loss.

Owns: :func:`ssim`, :func:`ssim_map`, :class:`PerceptualLoss`. The VGG16 term is used only when the
torchvision ImageNet weights exist locally (no download, no torchvision import): the file named by
``$NEURAS_VGG16_WEIGHTS`` or ``$TORCH_HOME/hub/checkpoints/vgg16-397923af.pth`` (TORCH_HOME defaults to
``~/.cache/torch``). Without it, training uses the SSIM term ("SSIM loss", not a perceptual loss).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from neuras_distill.errors import BadInputError

SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2


def _gaussian_window(window: int, sigma: float, channels: int, device, dtype=torch.float32) -> torch.Tensor:
    x = torch.arange(window, dtype=torch.float64) - (window - 1) / 2.0
    g = torch.exp(-(x * x) / (2.0 * sigma * sigma))
    g = (g / g.sum()).to(device=device, dtype=dtype)
    return g.view(1, 1, 1, window).expand(channels, 1, 1, window).contiguous()


def _blur(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Separable 'valid' gaussian filter of (B, C, h, w) -> (B, C, h-win+1, w-win+1)."""
    c = x.shape[1]
    x = F.conv2d(x, g, groups=c)
    return F.conv2d(x, g.transpose(2, 3), groups=c)


def ssim_map(img1: torch.Tensor, img2: torch.Tensor, window: int = 7, sigma: float = 1.5) -> torch.Tensor:
    """Per-pixel SSIM (data range 1) of (B, C, h, w) images -> (B, h-window+1, w-window+1), channel mean.

    Gaussian window, 'valid' filtering (no padding), fp32, C1 = 0.01^2, C2 = 0.03^2.
    """
    if img1.shape != img2.shape or img1.dim() != 4:
        raise ValueError(f"ssim needs two (B, C, h, w) tensors of one shape, got {tuple(img1.shape)}, "
                         f"{tuple(img2.shape)}")
    if min(img1.shape[-2:]) < window:
        raise ValueError(f"images {tuple(img1.shape[-2:])} are smaller than the SSIM window {window}")
    x, y = img1.float(), img2.float()
    g = _gaussian_window(window, sigma, x.shape[1], x.device)
    mu_x, mu_y = _blur(x, g), _blur(y, g)
    sxx = _blur(x * x, g) - mu_x * mu_x
    syy = _blur(y * y, g) - mu_y * mu_y
    sxy = _blur(x * y, g) - mu_x * mu_y
    num = (2 * mu_x * mu_y + SSIM_C1) * (2 * sxy + SSIM_C2)
    den = (mu_x * mu_x + mu_y * mu_y + SSIM_C1) * (sxx + syy + SSIM_C2)
    return (num / den).mean(dim=1)


def ssim(img1: torch.Tensor, img2: torch.Tensor, window: int = 7, mask: torch.Tensor | None = None,
         sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of (B, 3, h, w) patches in [0, 1] -> scalar.

    Args:
        mask: optional (B, h, w) bool/float; the SSIM map is averaged over pixels whose window centre is in
            the mask (cropped like the 'valid' map).
    """
    m = ssim_map(img1, img2, window, sigma)
    if mask is None:
        return m.mean()
    r = window // 2
    wgt = mask.float()[:, r:r + m.shape[1], r:r + m.shape[2]]
    return (m * wgt).sum() / wgt.sum().clamp_min(1.0)


# ---------------------------------------------------------------------------------------------- VGG16
VGG16_FILE = "vgg16-397923af.pth"
_VGG16_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]
_LAYERS = (3, 8, 15, 22)          # relu1_2, relu2_2, relu3_3, relu4_3
_MEAN = (0.485, 0.456, 0.406)
_STD = (0.229, 0.224, 0.225)


def vgg16_features() -> nn.Sequential:
    """torchvision's ``vgg16().features`` architecture (same module indices, so ``features.N.*`` keys load)."""
    layers: list[nn.Module] = []
    c = 3
    for v in _VGG16_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(c, v, kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            c = v
    return nn.Sequential(*layers)


def vgg16_weights_path() -> Path:
    """Where the weights are looked for: $NEURAS_VGG16_WEIGHTS, else $TORCH_HOME/hub/checkpoints/vgg16-397923af.pth."""
    env = os.environ.get("NEURAS_VGG16_WEIGHTS")
    if env:
        return Path(env).expanduser()
    home = Path(os.environ.get("TORCH_HOME", Path.home() / ".cache" / "torch")).expanduser()
    return home / "hub" / "checkpoints" / VGG16_FILE


class PerceptualLoss(nn.Module):
    """Mean L1 between frozen VGG16 features (relu1_2, 2_2, 3_3, 4_3), summed over layers.

    Inputs are (B, 3, h, w) images in [0, 1]; ImageNet normalisation is applied inside. Construction raises
    :class:`BadInputError` naming the expected file when the weights are absent or malformed.
    """

    def __init__(self, path: str | os.PathLike | None = None) -> None:
        super().__init__()
        self.path = Path(path).expanduser() if path is not None else vgg16_weights_path()
        ok, reason = self.available(self.path)
        if not ok:
            raise BadInputError(reason)
        try:
            state = torch.load(self.path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 - any unreadable file is a user problem
            raise BadInputError(f"cannot read VGG16 weights {self.path}: {exc}") from exc
        feats = vgg16_features()[: _LAYERS[-1] + 1]
        wanted = {k: v for k, v in feats.state_dict().items()}
        got = {}
        for key in wanted:
            src = state.get(f"features.{key}") if isinstance(state, dict) else None
            if src is None or tuple(src.shape) != tuple(wanted[key].shape):
                raise BadInputError(f"VGG16 weights {self.path} lack features.{key} of shape "
                                    f"{tuple(wanted[key].shape)} (expected torchvision's vgg16 state dict)")
            got[key] = src.float()
        feats.load_state_dict(got)
        feats.eval()
        for p in feats.parameters():
            p.requires_grad_(False)
        self.features = feats
        self.register_buffer("mean", torch.tensor(_MEAN).view(1, 3, 1, 1))
        self.register_buffer("std", torch.tensor(_STD).view(1, 3, 1, 1))

    @staticmethod
    def available(path: str | os.PathLike | None = None) -> tuple[bool, str]:
        """(True, path) when the weight file exists, else (False, a sentence saying where to put it)."""
        p = Path(path).expanduser() if path is not None else vgg16_weights_path()
        if p.is_file():
            return True, str(p)
        return False, (f"VGG16 weights not found at {p}; place torchvision's {VGG16_FILE} there or set "
                       "NEURAS_VGG16_WEIGHTS to its path (no download is attempted); the SSIM term is used instead")

    def train(self, mode: bool = True) -> "PerceptualLoss":
        super().train(mode)
        self.features.eval()
        return self

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        x = (pred.float() - self.mean) / self.std
        y = (target.float() - self.mean) / self.std
        loss = x.new_zeros(())
        for n, layer in enumerate(self.features):
            x, y = layer(x), layer(y)
            if n in _LAYERS:
                loss = loss + (x - y).abs().mean()
        return loss
