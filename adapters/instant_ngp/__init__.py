"""Instant-NGP (NVlabs/instant-ngp) NeRF snapshots, end to end (docs/formats.md §1).

* :mod:`.snapshot`: the file: container sniffing, the msgpack key tree, validation (:func:`read_snapshot`),
  and the writer used by tests and fixtures;
* :mod:`.frames`: :class:`NgpFrame`, the world (transforms.json) / ngp / network frames;
* :mod:`.field`: :class:`NgpField`, the network (hash grid, density and rgb MLPs, occupancy grid) as a Field;
* :mod:`.adapter`: :class:`InstantNGPAdapter`, the ``neuras_distill.adapters`` entry point.

Importing the package imports only the adapter class; torch, numpy and msgpack load when a file is sniffed
or read.
"""

from .adapter import InstantNGPAdapter

__all__ = ["InstantNGPAdapter"]
