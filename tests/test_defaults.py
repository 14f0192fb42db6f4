"""Defaults live in one place (config.py): the library's own defaults must be the configuration's, so a function
called without the configuration behaves like the pipeline (nerfstudio #3238 is this bug)."""

import inspect

import pytest

from neuras_distill.config import SkyboxConfig, TeacherConfig, TextureConfig, TrainConfig
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.shader import MLPShader
from neuras_distill.neural.skybox import SkyboxModel
from neuras_distill.neural.train import fit
from neuras_distill.render.volume import VolumeRenderer

CASES = [
    (NeuralTextureModel.__init__, TextureConfig(),
     {"feature_dim": "feature_dim", "num_codes": "num_codes", "hidden": "hidden", "num_layers": "num_layers",
      "use_vq": "quantize", "quantize_above": "quantize_above"}),
    (MLPShader.__init__, TextureConfig(), {"hidden": "hidden", "num_layers": "num_layers"}),
    (SkyboxModel.__init__, SkyboxConfig(), {"feature_dim": "feature_dim", "num_codes": "num_codes",
                                            "hidden": "hidden"}),
    (fit, TrainConfig(), {"lr": "lr", "texture_lr_scale": "texture_lr_scale", "batch_patches": "batch_patches",
                          "patch": "patch", "ssim_weight": "ssim_weight", "vq_warmup": "vq_warmup", "seed": "seed"}),
    (VolumeRenderer.__init__, TeacherConfig(), {"num_steps": "num_steps",
                                                "occupancy_resolution": "occupancy_resolution"}),
]


@pytest.mark.parametrize("function, config, names", CASES, ids=lambda c: getattr(c, "__qualname__", ""))
def test_library_defaults_are_the_configuration_defaults(function, config, names):
    params = inspect.signature(function).parameters
    for arg, key in names.items():
        assert params[arg].default == getattr(config, key), (function.__qualname__, arg)
