"""A tile's coarser levels of detail and their measured error (``tiles plan --levels N``).

Level 0 is the tile as ``run_tile`` distils it (``CITY/tiles/K/``). Level l (1 .. N-1) is the same tile distilled
again into ``CITY/levels/l/K/`` from the same teacher (level 0's stored stages are reused), with 1/4^l of its
faces, 1/2^l of its atlas side (at least :data:`MIN_SIDE`, and at least what its UV charts need: a fragmented
mesh keeps many charts at a quarter of the faces) and 1/4^l of its training steps or seconds, then cut to the
tile's box as level 0 is (``tile/``).

Error: a level's ``geometricError`` (metres: what 3D Tiles projects to pixels to choose a level) is measured
against level 0, never guessed. It is the larger of two figures:

* the surface's deviation: the 95th percentile of the distance from :data:`SAMPLES` area-weighted points on each
  mesh to the other (libigl), both ways;
* the level's texel: the edge of one texel on the surface, ``sqrt(world area / (uv area x side^2))``, the
  smallest detail its atlas holds.

The larger one, in metres, is the error a viewer sees when the level is shown where it covers one pixel. 3D Tiles
clients refine a tile when its ``geometricError`` projects to more than their target, 16 pixels by default
(3DTilesRendererJS's ``errorTarget``, CesiumJS's ``maximumScreenSpaceError``), so the error written is
:data:`TARGET_PX` times the measured one: at a client's default a level shows where its measured error is at most
one pixel, and a user who raises the target trades detail for bytes in those units. A level is never given less
error than the finer one below it, so errors grow up the chain.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

#: Smallest atlas side of a coarse level (texels).
MIN_SIDE = 64
#: Fewest faces, and fewest training steps, of a coarse level.
MIN_FACES, MIN_STEPS = 500, 100
#: Points sampled on each mesh for the deviation.
SAMPLES = 20000
#: The percentile of the deviation taken as the level's.
PERCENTILE = 95.0
#: 3D Tiles clients' default screen-space error target (pixels): the measured error is written times this.
TARGET_PX = 16.0


def level_folder(city: Path, level: int, index: int) -> Path:
    """Where level ``level`` of tile ``index`` is distilled (level 0: ``CITY/tiles/K``)."""
    return Path(city) / "tiles" / str(index) if level == 0 else Path(city) / "levels" / str(level) / str(index)


def level_overrides(cfg, level: int, side0: int) -> dict:
    """The settings of level ``level`` from level 0's configuration ``cfg`` and atlas side ``side0``."""
    scale = 4 ** level
    out = {"geometry": {"face_budget": max(MIN_FACES, cfg.geometry.face_budget // scale)},
           "texture": {"resolution": max(MIN_SIDE, int(side0) >> level)}}
    if cfg.train.steps:
        out["train"] = {"steps": max(MIN_STEPS, cfg.train.steps // scale)}
    if cfg.train.time_budget_s:
        out.setdefault("train", {})["time_budget_s"] = max(5.0, round(cfg.train.time_budget_s / scale, 1))
    return out


def atlas_side(run: Path) -> int:
    """The atlas side (texels, one page) of a finished run folder (its report.json)."""
    report = json.loads((Path(run) / "report.json").read_text("utf-8"))
    return int((report.get("mesh_stats") or {}).get("uv_resolution") or report["texture_resolution"][0])


def _area_samples(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int) -> np.ndarray:
    tri = vertices[faces].astype(np.float64)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(faces), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def texel_metres(vertices: np.ndarray, faces: np.ndarray, uvs: np.ndarray, side: int) -> float:
    """The edge of one texel on the surface: sqrt(world area / (uv area x side^2))."""
    tri = vertices[faces].astype(np.float64)
    world = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    t = uvs[faces].astype(np.float64)
    uv = 0.5 * np.abs((t[:, 1, 0] - t[:, 0, 0]) * (t[:, 2, 1] - t[:, 0, 1])
                      - (t[:, 2, 0] - t[:, 0, 0]) * (t[:, 1, 1] - t[:, 0, 1])).sum()
    return float(np.sqrt(world / max(uv * side * side, 1e-30)))


def level_error(fine, coarse, side: int) -> dict:
    """{"deviation_m", "texel_m", "error_m"} of the ``coarse`` bundle against the ``fine`` one (both world frame
    through their origins; ``side``: the coarse atlas side); ``error_m`` is the larger measured figure times
    :data:`TARGET_PX`, the level's ``geometricError``."""
    from ..geometry.raycast import raycasting_scene, surface_distance

    fv = fine.mesh.vertices.astype(np.float64) + np.asarray(fine.origin, np.float64)
    cv = coarse.mesh.vertices.astype(np.float64) + np.asarray(coarse.origin, np.float64)
    there = surface_distance(raycasting_scene(fv, fine.mesh.faces), _area_samples(cv, coarse.mesh.faces, SAMPLES, 0))
    back = surface_distance(raycasting_scene(cv, coarse.mesh.faces), _area_samples(fv, fine.mesh.faces, SAMPLES, 1))
    deviation = float(max(np.percentile(there, PERCENTILE), np.percentile(back, PERCENTILE)))
    texel = texel_metres(cv, coarse.mesh.faces, coarse.mesh.uvs, side)
    return {"deviation_m": deviation, "texel_m": texel, "error_m": TARGET_PX * max(deviation, texel)}


__all__ = ["MIN_FACES", "MIN_SIDE", "MIN_STEPS", "PERCENTILE", "SAMPLES", "TARGET_PX", "atlas_side", "level_error",
           "level_folder", "level_overrides", "texel_metres"]
