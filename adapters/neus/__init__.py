"""NeuS-family SDF checkpoints, end to end (docs/formats.md §2): Totoro97/NeuS and bennyguo/instant-nsr-pl.

* :mod:`.adapter`: :class:`NeuSAdapter`, the ``neuras_distill.adapters`` entry point (sniffing by content);
* :mod:`.loader`: :func:`load_neus_checkpoint`, file -> field (form detection, cameras, the VolSDF option);
* :mod:`.mlp_field`: :class:`NeuSField`, NeuS's MLPs (architecture inferred from the tensor shapes);
* :mod:`.hashgrid_field`: :class:`HashGridNeuSField`, instant-nsr-pl's hash grid and MLPs;
* :mod:`.nsr_config`: instant-nsr-pl run configs (defaults, ``parsed.yaml``, the grid config);
* :mod:`.base`: :class:`NeuSFamilyField`, what the two fields share (frame, sharpness, box, background,
  chunked world-frame ``geometry`` / ``radiance`` / ``sdf_and_gradient``);
* :mod:`.layers`: network pieces (positional encoding, weight-normalised linear layers, activations);
* :mod:`.frame`: :class:`SphereFrame`, the unit-sphere network frame in the world;
* :mod:`.cameras`: ``cameras_sphere.npz`` (projection matrices, scale matrix) to and from :class:`Cameras`.

Importing the package imports only the adapter class; torch loads when a checkpoint is sniffed or read.
"""

from .adapter import NeuSAdapter

__all__ = ["NeuSAdapter"]
