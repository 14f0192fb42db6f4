"""The finished tiles as a 3D Tiles 1.1 tileset (``neuras-distill tiles merge CITY --out CITY/tileset/``).

Owns :func:`merge_tiles`, :func:`tileset_json` and the layout of the folder it writes (docs/formats.md
"Tilesets"):

    tileset.json        3D Tiles 1.1: the root (no content, ``refine`` ADD) and one child per tile with its
                        ``.glb`` as content
    tiles/K.glb         tile K's cut bundle (``CITY/tiles/K/tile``) as ``export --format gltf`` writes it: the
                        plain texture, ``NEURAS_neural_material`` and the bundle inside, upright (+Y) by the
                        plan's up
    cameras.json        the plan's cameras ({"train", "test"} of ``Cameras.to_json``, world frame)
    .neuras-distill-tileset  marker: this folder is ours, so a later merge may replace it

Frames: 3D Tiles is z up and turns glTF content from +Y up to +Z up (its ``gltfUpAxis`` default), so a tile's
content is in the tileset frame ``M p`` of a world point p, M = (+Y -> +Z) @ (the glb's up rotation): the world
frame itself for a z-up capture. Bounding volumes are oriented boxes in that frame: each tile's is its mesh's
bounds within its box. Without a CRS the root has no transform (a local frame, metres as the field's units).
With ``crs`` (a projected CRS the scene's coordinates are in, ``tiles/crs.py``) the root's ``transform`` takes
the tileset frame to ECEF, exact at the scene box's centre, and each tile's own ``transform`` corrects it to be
exact at the tile's centre: the Earth's curvature then costs under a millimetre across a 150 m tile (the root's
expansion alone: 2.8 cm at 600 m).

Levels of detail (``tiles plan --levels N``): each tile is a chain of nodes, its coarsest level first, each
refined (``REPLACE``) by the next finer, down to full detail (``geometricError`` 0); a level's
``geometricError`` is its measured error against full detail (``tiles/levels.py``), and level l's content is
``tiles/K_l.glb``. The root (``refine`` ADD) holds the chains; its error is the scene's diagonal. Every node of a
chain has the tile's bounds over all its levels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import BadInputError
from .plan import read_plan
from .run import tile_done

MARKER = ".neuras-distill-tileset"
#: glTF's +Y up to 3D Tiles' +Z up, as a 3D Tiles client turns glTF content: (x, y, z) -> (x, -z, y).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def tileset_frame(up) -> np.ndarray:
    """(3, 3) M taking world points to the tileset frame, for the capture's ``up`` (3,)."""
    from ..export.gltf_up import rotation_onto_y

    return Y_UP_TO_Z_UP @ rotation_onto_y(up)


def oriented_box(lo, hi, frame: np.ndarray) -> list[float]:
    """3D Tiles ``box`` (12 numbers: centre, then the x, y and z half-axes) of the world box ``lo``..``hi`` in the
    tileset frame ``frame`` (3, 3)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    axes = [frame @ (np.eye(3)[k] * half[k]) for k in range(3)]
    return [float(v) for v in np.concatenate([frame @ centre, *axes])]


def _column_major(m: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(m, np.float64).T.reshape(-1)]


def level_uri(index: int, level: int) -> str:
    """The content of tile ``index`` at ``level`` (0: full detail)."""
    return f"tiles/{index}.glb" if level == 0 else f"tiles/{index}_{level}.glb"


def _chain(index: int, levels: list[dict], box: list[float]) -> dict:
    """Tile ``index``'s nodes, coarsest first, each refined (REPLACE) by the next finer: ``levels`` [{"level",
    "error_m"}] of its coarse levels (level 0, full detail, has geometricError 0)."""
    node = {"boundingVolume": {"box": box}, "geometricError": 0.0, "content": {"uri": level_uri(index, 0)}}
    for info in sorted(levels, key=lambda lv: lv["level"]):
        node = {"boundingVolume": {"box": box}, "geometricError": float(info["error_m"]), "refine": "REPLACE",
                "content": {"uri": level_uri(index, info["level"])}, "children": [node]}
    return node


def tileset_json(plan: dict, bounds: list[tuple[np.ndarray, np.ndarray]], generator: str, crs=None,
                 background=None, levels: list[list[dict]] | None = None) -> dict:
    """tileset.json for the plan's tiles with world ``bounds`` [(lo (3,), hi (3,))] of each tile's meshes; ``crs``:
    a projected CRS (``tiles/crs.projected_crs``) to place it on the globe, or None for a local frame;
    ``background``: (3,) the tiles' clear colour, recorded in ``asset.extras.neuras_background``; ``levels``: per
    tile its coarse levels (``tile.json``'s ``levels``), or None for full detail only."""
    frame = tileset_frame(plan["up"])
    scene = np.asarray(plan["scene_box"], np.float64)
    lo = np.min([b[0] for b in bounds], axis=0)
    hi = np.max([b[1] for b in bounds], axis=0)
    diagonal = float(np.linalg.norm(scene[1] - scene[0]))
    levels = levels or [[] for _ in plan["tiles"]]
    children = [_chain(tile["index"], tile_levels, oriented_box(b_lo, b_hi, frame))
                for tile, (b_lo, b_hi), tile_levels in zip(plan["tiles"], bounds, levels)]
    root = {"boundingVolume": {"box": oriented_box(lo, hi, frame)}, "geometricError": diagonal, "refine": "ADD",
            "children": children}
    asset = {"version": "1.1", "generator": generator,
             "extras": {"neuras_world_to_tileset": [[float(v) for v in row] for row in frame]}}
    if background is not None:
        asset["extras"]["neuras_background"] = [float(v) for v in np.asarray(background).reshape(3)]
    if crs is not None:
        from .crs import root_transform

        centre = 0.5 * (scene[0] + scene[1])
        placed = root_transform(crs, centre, frame)
        root["transform"] = _column_major(placed)
        inverse = np.linalg.inv(placed)
        for child, (b_lo, b_hi) in zip(children, bounds):
            child["transform"] = _column_major(inverse @ root_transform(crs, 0.5 * (b_lo + b_hi), frame))
        asset["extras"]["neuras_crs"] = crs.to_string()
    return {"asset": asset, "geometricError": diagonal, "root": root}


def merge_tiles(city, out, *, max_texture_size: int | None = None, crs: str | None = None) -> tuple[Path, int]:
    """Write the tileset folder ``out`` (module docstring) of the finished tiles in ``city``; (out, bytes).
    ``crs``: ``--crs EPSG:XXXXX``, the projected CRS of the scene's coordinates. BadInputError naming the
    unfinished tiles, an unknown or non-projected CRS, or an ``out`` that is not ours."""
    from .. import __version__
    from ..bake.bundle import load_bundle, read_bundle_file_bytes
    from ..export.folder_output import check_replaceable, write_folder
    from ..export.gltf import glb_bytes
    from ..export.texture_limit import DEFAULT_MAX_TEXTURE_SIZE, checked_limit

    city, out = Path(city), Path(out)
    plan = read_plan(city)
    if crs is not None:
        from .crs import projected_crs

        crs = projected_crs(crs)                       # before any work: a bad CRS is one line
    check_replaceable(out, MARKER, "tileset folder")
    missing = [t["index"] for t in plan["tiles"] if not tile_done(city, plan, t["index"])]
    if missing:
        raise BadInputError(f"tiles {', '.join(map(str, missing))} of {len(plan['tiles'])} are not finished: run "
                            f"them (`neuras-distill tiles run {city} --tile K`, or without --tile for all)")
    limit = checked_limit(max_texture_size or DEFAULT_MAX_TEXTURE_SIZE)
    up = np.asarray(plan["up"], np.float64)
    files: dict[str, bytes] = {}
    bounds, background = [], None
    from .levels import level_folder

    chains = []
    for tile in plan["tiles"]:
        k = tile["index"]
        record = json.loads((city / "tiles" / str(k) / "tile.json").read_text("utf-8"))
        coarse = record.get("levels") or []
        chains.append(coarse)
        lows, highs = [], []
        for level in [0, *(lv["level"] for lv in coarse)]:
            folder = level_folder(city, level, k) / "tile"
            bundle = load_bundle(folder)
            background = bundle.background_color if background is None else background
            world = bundle.mesh.vertices.astype(np.float64) + bundle.origin
            lows.append(world.min(0))
            highs.append(world.max(0))
            files[level_uri(k, level)] = glb_bytes(bundle, read_bundle_file_bytes(folder), limit, up)
        bounds.append((np.min(lows, axis=0), np.max(highs, axis=0)))
    generator = f"neuras-distill {__version__}"
    tileset = tileset_json(plan, bounds, generator, crs, background, chains)
    files["tileset.json"] = (json.dumps(tileset, indent=1) + "\n").encode("utf-8")
    from ..render.cameras import Cameras

    cameras = Cameras.from_json(json.loads((city / plan["cameras"]).read_text("utf-8")))
    files["cameras.json"] = json.dumps({"train": cameras[plan["train"]].to_json(),
                                        "test": cameras[plan["test"]].to_json()}).encode("utf-8")
    files[MARKER] = json.dumps({"generator": "neuras-distill", "version": __version__}).encode("utf-8")
    write_folder(out, files)
    return out, sum(len(v) for v in files.values())


__all__ = ["MARKER", "Y_UP_TO_Z_UP", "merge_tiles", "oriented_box", "tileset_frame", "tileset_json"]
