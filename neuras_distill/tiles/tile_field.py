"""One tile's field: the scene's field with its foreground box replaced by the tile's training box.

Owns :class:`TileField`. The teacher marches, the mesh is extracted and the skyboxes would begin at the field's
``aabb``; a tile's run sees the field only inside its box (the tile grown by the plan's overlap margin), so its
teacher images show the tile's own surfaces (a neighbour's building is not there to hide them) and its mesh
ends at the box. Everything else is the scene's field, called unchanged. Frames: world, as the field's.
"""

from __future__ import annotations

import numpy as np
import torch

#: Optional Field members a tile passes on from the scene's field (docs/contract.md). Not passed on: the field's
#: own ``cameras`` and ``default_cameras`` (the plan gives each tile its cameras), ``occupancy_grid`` (it covers
#: the scene's box, not the tile's), ``lane_shifts`` (the scene's evaluation, not the tile's) and ``far_region``
#: (beyond a tile's box lie its neighbours, which the far region would render into the tile's teacher images;
#: what lies beyond the whole scene is the far field's, not a tile's).
PASSED_ON = ("background", "background_color", "inv_s", "unbounded", "surface_level", "preset")


class TileField:
    """Field members: ``kind``, ``aabb`` (2, 3) float32 = the tile's training box (world), ``geometry``,
    ``radiance``, ``source_digest`` (the scene field's fingerprint and the box), and :data:`PASSED_ON` where the
    scene's field has them."""

    def __init__(self, field, box, fingerprint: str):
        box = np.asarray(box, np.float64).reshape(2, 3)
        self.scene_field = field
        self.kind = field.kind
        self.aabb = torch.tensor(box, dtype=torch.float32)
        self.source_digest = f"tile {box.tolist()} of {fingerprint}"
        for name in PASSED_ON:
            if hasattr(field, name):
                setattr(self, name, getattr(field, name))

    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        return self.scene_field.geometry(x)

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        return self.scene_field.radiance(x, d)


__all__ = ["PASSED_ON", "TileField"]
