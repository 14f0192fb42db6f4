"""Measurements that decide what a scene does not need, each reported as ``{component, reason}``.

* view direction: the field's colour at surface points is compared across view directions; when it barely
  changes, the MLP shader gets no view input (and the generated GLSL has none).
* skyboxes: a field whose background is one constant colour (or that has no background) needs none.
"""

from __future__ import annotations

import numpy as np
import torch

from ..geometry.mesh import MeshData


def measure_view_dependence(field, mesh: MeshData, *, num_points: int = 2048, num_dirs: int = 8,
                            seed: int = 0) -> float:
    """Mean over surface points and channels of the standard deviation of colour (0..1) across ``num_dirs``
    random view directions that reach the point from outside (the hemisphere around the face normal)."""
    rng = np.random.default_rng(seed)
    v, f = mesh.vertices.astype(np.float64), mesh.faces
    if len(f) == 0:
        return 0.0
    pick = rng.choice(len(f), size=min(num_points, len(f)), replace=False)
    tri = v[f[pick]]
    bary = rng.dirichlet(np.ones(3), size=len(pick))
    points = np.einsum("nk,nkc->nc", bary, tri)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    dirs = rng.normal(size=(len(pick), num_dirs, 3))
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    # Directions of travel point into the surface: d . n < 0.
    flip = np.einsum("ndc,nc->nd", dirs, normals) > 0
    dirs[flip] *= -1
    x = torch.as_tensor(np.repeat(points, num_dirs, axis=0), dtype=torch.float32)
    d = torch.as_tensor(dirs.reshape(-1, 3), dtype=torch.float32)
    with torch.no_grad():
        rgb = field.radiance(x, d).reshape(len(pick), num_dirs, 3).double()
    return float(rgb.std(dim=1).mean())


def background_is_constant(field) -> tuple[bool, str]:
    """(True, description) when every ray that misses the foreground sees one constant colour."""
    if getattr(field, "unbounded", False):
        return False, "the field is unbounded: content lies outside its box"
    if callable(getattr(field, "background", None)):
        dirs = torch.nn.functional.normalize(torch.randn(512, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
        with torch.no_grad():
            bg = field.background(dirs).double()
        spread = float((bg - bg.mean(0)).abs().max())
        if spread > 1.0 / 255.0:
            return False, f"the background changes with direction (max deviation {spread:.3f})"
        colour = bg.mean(0).tolist()
    else:
        colour = background_color(field).tolist()
    return True, "every ray that misses the foreground sees one constant colour " + \
        "(" + ", ".join(f"{c:.3f}" for c in colour) + "); it is the clear colour"


def background_color(field) -> torch.Tensor:
    """(3,) float32 constant background colour of a field (black when it has none)."""
    bg = getattr(field, "background_color", None)
    if bg is None:
        return torch.zeros(3)
    return torch.as_tensor(bg, dtype=torch.float32).reshape(3)
