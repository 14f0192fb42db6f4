"""nerfstudio runs: the nerfacto field in plain PyTorch, without nerfstudio or tiny-cuda-nn (docs/formats.md §3).

* :mod:`.run`: the run folder (config.yml read with its python tags as data, the newest checkpoint,
  dataparser_transforms.json) and the nerfacto settings;
* :mod:`.nerfacto`: the field's network (hash grid, MLPs, spherical harmonics, scene contraction) from the
  checkpoint's state dict;
* :mod:`.field`: the network in the dataset's frame as a neuras-distill density field;
* :mod:`.adapter`: :class:`NerfstudioAdapter` for the adapter registry.
"""

from .adapter import NerfstudioAdapter

__all__ = ["NerfstudioAdapter"]
