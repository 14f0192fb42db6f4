"""Instant-NGP's coordinate frames and the maps between them and the user's transforms.json frame.

This module owns :class:`NgpFrame`. Three frames (docs/formats.md §1.8):

* **world** ("nerf" space): the frame of the user's ``transforms.json``; OpenGL camera axes (x right, y up,
  z backward). Everything neuras-distill hands out (field, cameras, meshes) is in this frame.
* **ngp** space: ``p_ngp = cyc(p_world * scale + offset)`` with ``cyc(a, b, c) = (b, c, a)`` (the offset is
  added in world axis order, before the cycle). Camera matrices there have axes x right, y down, z forward.
  Datasets converted from Mitsuba (``from_mitsuba``) skip the cycle and flip camera x and z instead.
* **network** space: ``x_net = (p_ngp - (0.5 - aabb_scale / 2)) / aabb_scale``, the hash grid's input cube
  [0, 1]^3.

Densities are per unit length of the frame they are expressed in: ``sigma_world = sigma_ngp * scale``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass(frozen=True)
class NgpFrame:
    """The transform between world (transforms.json) and ngp/network space of one snapshot.

    Attributes:
        scale: world -> ngp length factor (ngp default 0.33).
        offset: (3,) added after scaling, in world axis order (ngp default 0.5, 0.5, 0.5).
        aabb_scale: side of the network cube in ngp units (power of two, 1..128).
        from_mitsuba: Mitsuba-converted dataset (no axis cycle).
    """

    scale: float = 0.33
    offset: tuple = (0.5, 0.5, 0.5)
    aabb_scale: float = 1.0
    from_mitsuba: bool = False

    # ------------------------------------------------------------------ points and directions
    def _offset(self, like: torch.Tensor) -> torch.Tensor:
        return torch.as_tensor(self.offset, dtype=like.dtype, device=like.device)

    def _cycle(self, a: torch.Tensor) -> torch.Tensor:
        """(..., 3) world axis order -> ngp axis order."""
        return a if self.from_mitsuba else a[..., [1, 2, 0]]

    def _uncycle(self, a: torch.Tensor) -> torch.Tensor:
        """(..., 3) ngp axis order -> world axis order."""
        return a if self.from_mitsuba else a[..., [2, 0, 1]]

    def world_to_ngp(self, x: torch.Tensor) -> torch.Tensor:
        """(..., 3) world points -> ngp points."""
        return self._cycle(x * self.scale + self._offset(x))

    def ngp_to_world(self, p: torch.Tensor) -> torch.Tensor:
        """(..., 3) ngp points -> world points."""
        return (self._uncycle(p) - self._offset(p)) / self.scale

    def world_dirs_to_ngp(self, d: torch.Tensor) -> torch.Tensor:
        """(..., 3) world directions -> ngp directions (a pure axis permutation; lengths are kept)."""
        return self._cycle(d)

    def net_min(self) -> float:
        """Lower corner (all three axes) of the network cube in ngp space."""
        return 0.5 - 0.5 * float(self.aabb_scale)

    def world_to_net(self, x: torch.Tensor) -> torch.Tensor:
        """(..., 3) world points -> network-space points (the hash grid's [0, 1]^3 cube)."""
        return (self.world_to_ngp(x) - self.net_min()) / float(self.aabb_scale)

    def ngp_box_to_world(self, lo, hi) -> torch.Tensor:
        """An axis-aligned ngp box [lo, hi] -> (2, 3) world box (the map is a scaled axis permutation)."""
        corners = torch.tensor([list(lo), list(hi)], dtype=torch.float64)
        w = self.ngp_to_world(corners)
        return torch.stack([w.min(0).values, w.max(0).values]).float()

    def world_box_to_ngp(self, box) -> torch.Tensor:
        """(2, 3) world box -> (2, 3) ngp box."""
        p = self.world_to_ngp(torch.as_tensor(box, dtype=torch.float64).reshape(2, 3))
        return torch.stack([p.min(0).values, p.max(0).values])

    # ------------------------------------------------------------------ camera matrices
    def ngp_c2w_to_world(self, m: np.ndarray) -> np.ndarray:
        """(3, 4) ngp camera-to-world (x right, y down, z forward) -> (4, 4) world camera-to-world in the
        OpenGL convention (instant-ngp's ``ngp_matrix_to_nerf``)."""
        m = np.asarray(m, dtype=np.float64).reshape(3, 4).copy()
        if self.from_mitsuba:
            m[:, 0] *= -1.0
            m[:, 2] *= -1.0
        else:
            m = m[[2, 0, 1], :]
        m[:, 1] *= -1.0
        m[:, 2] *= -1.0
        m[:, 3] = (m[:, 3] - np.asarray(self.offset, dtype=np.float64)) / self.scale
        out = np.eye(4)
        out[:3] = m
        return out

    def world_c2w_to_ngp(self, c2w: np.ndarray) -> np.ndarray:
        """(4, 4) or (3, 4) world camera-to-world (OpenGL) -> (3, 4) ngp matrix (``nerf_matrix_to_ngp``)."""
        m = np.asarray(c2w, dtype=np.float64)[:3, :4].copy()
        m[:, 1] *= -1.0
        m[:, 2] *= -1.0
        m[:, 3] = m[:, 3] * self.scale + np.asarray(self.offset, dtype=np.float64)
        if self.from_mitsuba:
            m[:, 0] *= -1.0
            m[:, 2] *= -1.0
        else:
            m = m[[1, 2, 0], :]
        return m
