"""What the shader takes besides the features, as the pipeline chose it: the hand-off from the mesh's choices
(``pipeline/choices.py``) to the model (``NeuralTextureModel.for_atlas``), the G-buffer stage's view inputs and
the report."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class ShaderInputs:
    """What the shader takes besides the features: ``use_viewdir`` (with the ``view_spread`` measured, None when
    not measured), ``use_facing`` (|n . d|, for a fringe shell), ``core_viewdir`` (the core shader's own
    choice on a two-layer mesh; None: as ``use_viewdir``), ``reflect`` (the direction input is the view
    direction reflected about the shading normal, ``texture.view_input``) and ``normal_roughness_deg`` (the
    mesh's ``MeshData.normal_roughness_deg`` at ``texture.normal_smoothing`` rounds, None: not measured)."""

    use_viewdir: bool
    view_spread: float | None
    use_facing: bool
    core_viewdir: bool | None
    reflect: bool = False
    normal_roughness_deg: float | None = None
