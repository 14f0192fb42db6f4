"""Defaults live in one place (config.py): the library's own defaults must be the configuration's, so a function
called without the configuration behaves like the pipeline (nerfstudio #3238 is this bug)."""

import inspect

import pytest

from neuras_distill.config import GeometryConfig, SkyboxConfig, TeacherConfig, TextureConfig, TrainConfig
from neuras_distill.geometry.extract import extract_surface, unwrap_surface
from neuras_distill.geometry.unwrap import unwrap
from neuras_distill.geometry.visibility import cull_unseen_faces
from neuras_distill.render.occupancy import OccupancyGrid
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.shader import MLPShader
from neuras_distill.neural.skybox import SkyboxModel
from neuras_distill.neural.train import fit
from neuras_distill.render.volume import VolumeRenderer

CASES = [
    (NeuralTextureModel.__init__, TextureConfig(),
     {"feature_dim": "feature_dim", "num_codes": "num_codes", "hidden": "hidden", "num_layers": "num_layers",
      "use_vq": "quantize", "quantize_above": "quantize_above", "coarse_factor": "coarse_factor"}),
    (MLPShader.__init__, TextureConfig(), {"hidden": "hidden", "num_layers": "num_layers"}),
    (SkyboxModel.__init__, SkyboxConfig(), {"feature_dim": "feature_dim", "hidden": "hidden"}),
    (unwrap_surface, GeometryConfig(), {"unwrap_timeout_s": "unwrap_timeout_s"}),
    (unwrap, GeometryConfig(), {"timeout_s": "unwrap_timeout_s"}),
    (VolumeRenderer.__init__, TeacherConfig(), {"num_steps": "num_steps", "far_steps": "far_steps",
                                                "occupancy_resolution": "occupancy_resolution"}),
    (OccupancyGrid.from_field, TeacherConfig(), {"resolution": "occupancy_resolution"}),
    (cull_unseen_faces, GeometryConfig(), {"margin_deg": "cull_margin_deg"}),
]


@pytest.mark.parametrize("function, config, names", CASES, ids=lambda c: getattr(c, "__qualname__", ""))
def test_library_defaults_are_the_configuration_defaults(function, config, names):
    params = inspect.signature(function).parameters
    for arg, key in names.items():
        assert params[arg].default == getattr(config, key), (function.__qualname__, arg)


# steps and time_budget_s reach fit from the run's training plan, which starts from the section's values
@pytest.mark.parametrize("function, section, planned", [(fit, TrainConfig(), {"steps", "time_budget_s"}),
                                                        (extract_surface, GeometryConfig(), set())],
                         ids=["fit", "extract_surface"])
def test_a_function_that_takes_a_section_whole_defaults_to_the_configuration(function, section, planned):
    params = inspect.signature(function).parameters
    assert params["config"].default == section
    own = set(section.__dataclass_fields__) & set(params) - planned
    assert not own, f"{function.__qualname__} reads {sorted(own)} from its section, not from its own arguments"


def test_the_skybox_models_codebook_is_the_automatic_one_for_a_sky():
    """``skybox.num_codes`` 0 is automatic (``pipeline.rules.SKY_CODES``): the model's default is a sky's."""
    from neuras_distill.pipeline.rules import SKY_CODES

    assert SkyboxConfig().num_codes == 0
    assert inspect.signature(SkyboxModel.__init__).parameters["num_codes"].default == SKY_CODES[0]
