"""A nerfstudio nerfacto run as a neuras-distill density field, in the user's data frame.

This module owns :class:`NerfstudioField` (the Field contract, docs/contract.md): :class:`.nerfacto.NerfactoNetwork`
evaluated through the dataparser's transform, so the field, its box and the cameras are in the frame of the
dataset's ``transforms.json`` (metric when the capture was): ``x_ns = scale * (R x + t)`` with ``[R | t]`` and
``scale`` from ``dataparser_transforms.json`` (a run without it is refused), directions ``d_ns = R d``, density
``sigma = scale * sigma_ns`` per data-frame unit.

Foreground box: where the density exceeds :data:`BOX_DENSITY` (per nerfstudio unit) on a grid over the scene box
[-1, 1]^3 (nerfstudio's frame), without floaters (connected blobs under :data:`FLOATER_MASS_FRACTION` of the
largest blob's density mass), grown by one cell; ``--foreground-box`` overrides it. Density that touches the
scene box's faces, or rays leaving the box that turn opaque within 16 nerfstudio units, mean content beyond it:
``unbounded``, and then ``far_region``, which the teacher marches out to nerfstudio's far plane (the skyboxes
learn what it draws).

Background: config.yml's ``background_color``: ``white`` / ``black`` are constants; ``random`` renders as black in
nerfstudio's evaluation (no background is blended); ``last_sample`` (nerfacto's default) is the colour of the last
sample at the far plane: :meth:`NerfstudioField.background` evaluates the field at ``far_plane`` along each
direction from the scene box's centre.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from neuras_distill.errors import require
from neuras_distill.render.far_region import FarRegion

from .nerfacto import NerfactoNetwork
from .run import NerfactoSettings, NerfstudioRun

#: Density (per nerfstudio unit) above which a grid cell belongs to the foreground box.
BOX_DENSITY = 1.0
#: Connected blobs of such cells whose density mass is under this fraction of the largest blob's are floaters.
FLOATER_MASS_FRACTION = 0.005
#: The field holds far content (ground, buildings beyond the scene box) when rays from the box's centre become
#: opaque within FAR_PROBE_RADIUS nerfstudio units in at least this share of the directions.
FAR_CONTENT_FRACTION = 0.05
FAR_PROBE_RADIUS = 16.0
_BOX_GRID = 96


class NerfstudioField:
    """Field members: ``kind = "density"``, ``aabb`` (2, 3) data frame, ``geometry``, ``radiance``,
    ``background_color`` or ``background``, ``unbounded``, ``far_region`` (None without scene contraction),
    ``default_cameras``, plus
    ``frame`` ("data"), ``settings``, ``notes``."""

    kind = "density"

    def __init__(self, run: NerfstudioRun, network: NerfactoNetwork, settings: NerfactoSettings, *,
                 foreground_box=None):
        self.network = network
        self.settings = settings
        self._run = run                  # the run's files (private: not part of the field's fingerprint)
        self.pose_adjustment = None      # the camera optimizer's (K, 6) corrections, set by the adapter
        self.notes = list(settings.notes)
        if network.layout != "torch":
            self.notes.append(f"parameters in tiny-cuda-nn's layout, {network.layout}: evaluated in float32 here "
                              "(tcnn evaluates in half precision: values agree to about 1e-3 relative)")
        self.frame = "data"
        t = torch.as_tensor(run.dataparser["transform"], dtype=torch.float64)
        self.scale = float(run.dataparser["scale"])
        self.rotation = t[:, :3].float()
        self.translation = t[:, 3].float()
        self._rotation64, self._translation64 = t[:, :3], t[:, 3]
        if foreground_box is not None:
            box = torch.as_tensor(foreground_box, dtype=torch.float64).reshape(2, 3)
            require(bool((box[1] > box[0]).all()), f"--foreground-box: min must be below max on every axis, got "
                                                   f"{box.tolist()}")
            self.aabb, self.unbounded = box.float(), True
            self.foreground_reason = "--foreground-box"
        else:
            self.aabb, self.unbounded, self.foreground_reason = self._foreground()
        # the space beyond the box, as nerfstudio's collider and proposal sampler see it (data-frame distances:
        # nerfstudio's are ``scale`` times larger; its sampling turns to disparity one nerfstudio unit out), when
        # the field holds content there: an untrained contracted space is a faint fog no capture constrained
        if not settings.disable_scene_contraction and not self.unbounded and self._far_content():
            self.unbounded = True
            self.foreground_reason += "; density beyond the scene box (its contracted space): the far region"
        self.far_region = (FarRegion(near=settings.near_plane / self.scale, far=settings.far_plane / self.scale,
                                     pivot=1.0 / self.scale)
                           if self.unbounded and not settings.disable_scene_contraction else None)
        background = settings.background_color
        if background in ("white", "black", "random"):
            self.background_color = torch.full((3,), 1.0 if background == "white" else 0.0)
        else:
            self.background = self._last_sample_background

    # ------------------------------------------------------------------ frames
    def to_nerfstudio(self, x: torch.Tensor) -> torch.Tensor:
        """Data-frame points (N, 3) -> nerfstudio-frame points."""
        return self.scale * (x.float() @ self.rotation.to(x.device).T + self.translation.to(x.device))

    def from_nerfstudio_box(self, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
        """The data-frame axis-aligned box (2, 3) around a nerfstudio-frame box's 8 corners (float64 math)."""
        corners = torch.tensor([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)], dtype=torch.float64)
        pts = lo.double() + corners * (hi.double() - lo.double())
        world = (pts / self.scale - self._translation64) @ self._rotation64
        return torch.stack([world.min(0).values, world.max(0).values])

    # ------------------------------------------------------------------ Field contract
    def geometry(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, 3) data frame -> density (N,) per data-frame unit."""
        return self.scale * self.network.density(self.to_nerfstudio(x))

    def radiance(self, x: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """x (N, 3), d (N, 3) unit directions of travel (data frame) -> (N, 3) colour in [0, 1]."""
        d_ns = d.float() @ self.rotation.to(d.device).T
        return self.network.rgb(self.to_nerfstudio(x), d_ns)

    def _last_sample_background(self, d: torch.Tensor) -> torch.Tensor:
        """(N, 3) colour of the last sample (at the far plane) along data-frame directions d from the scene
        box's centre: what nerfstudio blends behind each ray with ``background_color: last_sample``."""
        d_ns = torch.nn.functional.normalize(d.float() @ self.rotation.to(d.device).T, dim=-1)
        centre = self.network.scene_box.mean(0).to(d.device)
        far = centre + self.settings.far_plane * d_ns
        return self.network.rgb(far, d_ns)

    def default_cameras(self, n: int, width: int = 512, height: int = 512, *, held_out_every: int = 12):
        """An orbit framing the foreground box (the run stores no cameras: pass ``--cameras`` for the
        dataset's)."""
        from neuras_distill.scenes.analytic import orbit_framing

        return orbit_framing(self.aabb, n, width, height)

    @property
    def split(self) -> tuple:
        """(eval_mode, eval_interval, train_split_fraction) of the run's data parser."""
        return self.settings.split

    def dataset_transforms(self):
        """(the run's dataset ``transforms.json`` or None, a phrase saying where it was found or why not): the
        cameras a run without ``--cameras`` trains on (:func:`.run.dataset_transforms`)."""
        from .run import dataset_transforms

        return dataset_transforms(self._run)

    def viewer_frame(self) -> dict:
        """The frame nerfstudio's viewer draws and writes camera paths in, as a map from this field's:
        ``{"kind": "nerfstudio dataparser", "transform": (3, 4) [R | t], "scale": s}``, ``x_ns = s (R x + t)``
        (``neuras_distill.render.camera_path.to_dataset_frame`` undoes it)."""
        transform = torch.cat([self._rotation64, self._translation64[:, None]], dim=1)
        return {"kind": "nerfstudio dataparser", "transform": transform.tolist(), "scale": self.scale}

    def corrected_cameras(self, cameras, names: list[str]):
        """The dataset's cameras (``transforms.json`` frames ``names``) with the camera optimizer's pose corrections
        of the frames nerfstudio trained on (:func:`.cameras.corrected_cameras`): (cameras, count corrected)."""
        from .cameras import corrected_cameras

        return corrected_cameras(cameras, names, self)

    def exported_cameras(self, path, width: int | None, height: int | None, focal: float | None):
        """The cameras of an ``ns-export cameras`` file (poses in nerfstudio's frame) in this field's frame, with
        the given image size and focal length in pixels (:func:`.cameras.exported_cameras`)."""
        from .cameras import exported_cameras

        return exported_cameras(path, self, width, height, focal)

    # ------------------------------------------------------------------ foreground
    @torch.no_grad()
    def _foreground(self) -> tuple[torch.Tensor, bool, str]:
        from scipy import ndimage

        r = _BOX_GRID
        axis = (torch.arange(r, dtype=torch.float32) + 0.5) / r * 2.0 - 1.0
        grid = torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), dim=-1).reshape(-1, 3)
        sigma = torch.cat([self.network.density(grid[i:i + 2**16]) for i in range(0, grid.shape[0], 2**16)])
        sigma = sigma.reshape(r, r, r).numpy()
        occupied = sigma > BOX_DENSITY
        require(bool(occupied.any()), "the nerfstudio field has no density above "
                                      f"{BOX_DENSITY} anywhere in its scene box: an untrained or empty run")
        # floaters: space no training ray constrained holds small blobs of density; they neither make the
        # scene unbounded nor stretch its box (the nerfstudio fixture: 80 blobs, each under 0.01% of the mass)
        labels, count = ndimage.label(occupied)
        mass = np.asarray(ndimage.sum(sigma, labels, np.arange(1, count + 1)))
        keep = np.flatnonzero(mass >= FLOATER_MASS_FRACTION * mass.max()) + 1
        idx = torch.from_numpy(np.argwhere(np.isin(labels, keep)))
        cell = 2.0 / r
        lo = (-1.0 + (idx.min(0).values - 1).clamp(min=0) * cell)
        hi = (-1.0 + (idx.max(0).values + 2).clamp(max=r) * cell)
        touches = bool((idx.min(0).values == 0).any() or (idx.max(0).values == r - 1).any())
        dropped = count - len(keep)
        reason = (f"density above {BOX_DENSITY} per nerfstudio unit on a {r}^3 grid over the scene box"
                  + (f", without {dropped} floater{'s' if dropped != 1 else ''} (blobs under "
                     f"{100 * FLOATER_MASS_FRACTION:g}% of the largest one's density mass)" if dropped else "")
                  + ("; it reaches the box's faces: content beyond goes to the skyboxes" if touches else ""))
        return self.from_nerfstudio_box(lo.double(), hi.double()).float(), touches, reason

    @torch.no_grad()
    def _far_content(self) -> bool:
        """Whether the space beyond the scene box holds content: rays from the box's centre, from where they leave
        the box out to :data:`FAR_PROBE_RADIUS` nerfstudio units, become opaque (> 0.5) in at least
        :data:`FAR_CONTENT_FRACTION` of the directions (the ground, a backdrop; an untrained contracted space is a
        faint fog that stays transparent over that distance)."""
        n = 512
        k = torch.arange(n, dtype=torch.float64) + 0.5
        z = 1.0 - 2.0 * k / n
        phi = math.pi * (3.0 - math.sqrt(5.0)) * k
        d = torch.stack([torch.sqrt(1 - z * z) * torch.cos(phi), torch.sqrt(1 - z * z) * torch.sin(phi), z], -1)
        t0 = 1.0 / d.abs().amax(dim=-1)                               # where each ray leaves [-1, 1]^3
        s = torch.linspace(0.0, 1.0, 129, dtype=torch.float64)
        t = 1.0 / (1.0 / t0[:, None] + s[None] * (1.0 / FAR_PROBE_RADIUS - 1.0 / t0[:, None]))   # disparity
        mid, dt = 0.5 * (t[:, 1:] + t[:, :-1]), t[:, 1:] - t[:, :-1]
        pts = (mid[..., None] * d[:, None, :]).reshape(-1, 3).float()
        sigma = torch.cat([self.network.density(pts[i:i + 2**16]) for i in range(0, pts.shape[0], 2**16)])
        tau = (sigma.double().reshape(n, -1).clamp(min=0) * dt).sum(-1)
        return bool(((1.0 - torch.exp(-tau)) > 0.5).double().mean() >= FAR_CONTENT_FRACTION)

    def __repr__(self) -> str:
        s = self.settings
        return (f"NerfstudioField({s.method}, {self.network.layout} layout, L{s.num_levels} F{s.features_per_level} "
                f"T2^{s.log2_hashmap_size}, frame={self.frame}, scale={self.scale:.4g}, aabb={self.aabb.tolist()})")

