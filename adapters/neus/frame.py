"""NeuS's normalised frame: :class:`SphereFrame` (docs/formats.md §2.3).

Both NeuS pipelines train in a unit-sphere frame given by a similarity ``scale_mat`` (``cameras_sphere.npz``):
``p_world = s·Q·p + t`` (NeuS: ``s = scale_mat[0, 0]``, ``Q = I``). The fields live in the user's world frame:
points are mapped into the network frame, signed distances are multiplied by ``s`` (world units), ``inv_s`` is
divided by ``s`` (the same opacities).
"""

from __future__ import annotations

import numpy as np
import torch


class SphereFrame:
    """The similarity ``p_world = s·Q·p + t`` from a network frame to the world (``Q`` a rotation, s > 0)."""

    def __init__(self, scale_mat: np.ndarray | None = None):
        from .cameras import check_similarity, similarity_parts

        m = np.eye(4) if scale_mat is None else check_similarity(scale_mat, "scale_mat")
        s, q, t = similarity_parts(m)
        self.matrix = m
        self.scale = float(s)
        self.rotation = torch.as_tensor(q, dtype=torch.float32)
        self.translation = torch.as_tensor(t, dtype=torch.float32)
        self._identity_rot = bool(np.allclose(q, np.eye(3), atol=1e-12))

    def __repr__(self) -> str:
        return f"SphereFrame(scale={self.scale:.6g}, translation={self.translation.tolist()})"

    def to_local(self, x: torch.Tensor) -> torch.Tensor:
        """World points (N, 3) -> network-frame points ``Qᵀ (x − t) / s`` (dtype and device of x)."""
        p = x - self.translation.to(x)
        if not self._identity_rot:
            p = p @ self.rotation.to(x)
        return p / self.scale

    def dir_to_local(self, d: torch.Tensor) -> torch.Tensor:
        """World directions (N, 3) -> network-frame directions ``Qᵀ d`` (lengths kept)."""
        return d if self._identity_rot else d @ self.rotation.to(d)

    def to_world(self, p: torch.Tensor) -> torch.Tensor:
        """Network-frame points (N, 3) -> world points."""
        p = p * self.scale
        if not self._identity_rot:
            p = p @ self.rotation.to(p).T
        return p + self.translation.to(p)

    def box_to_world(self, half: float) -> torch.Tensor:
        """(2, 3) world aabb of the network-frame cube ``[-half, half]^3``."""
        corners = torch.tensor([[i, j, k] for i in (-1.0, 1.0) for j in (-1.0, 1.0) for k in (-1.0, 1.0)]) * half
        w = self.to_world(corners)
        return torch.stack([w.min(0).values, w.max(0).values])

