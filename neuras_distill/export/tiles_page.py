"""A page that streams a tileset with the neural look: ``neuras-distill export CITY/tileset --format 3dtiles
--three THREE_DIR --tiles-renderer TILES_DIR --out DIR``.

Owns :func:`export_3dtiles` and the layout of the folder it writes: the tileset that ``tiles merge`` wrote, streamed
by 3DTilesRendererJS (npm ``3d-tiles-renderer``) on three.js, each tile's ``.glb`` loaded by three.js's GLTFLoader
with our plugin (``web/neuras-three.js``), so the tiles play their ``NEURAS_neural_material``; any other 3D Tiles
client (CesiumJS) opens ``tileset/tileset.json`` itself and shows the plain textures. Nothing is fetched from
outside the folder.

Layout of DIR::

    index.html              the page (``web/tiles.html``): ``?camera=N`` the tiles from held-out camera N once what
                            it needs is loaded (``window.neurasReady``, ``window.neurasStats``), ``&plain`` without
                            the plugin
    neuras-three.js         the plugin (package data, copied unchanged)
    tileset/                the tileset folder as ``tiles merge`` wrote it (tileset.json, tiles/K.glb, cameras.json)
    three/                  from THREE_DIR: the modules the page and 3DTilesRendererJS import (as ``export/threejs.py``)
    3d-tiles-renderer/      from TILES_DIR: package.json, LICENSE and ``build/index.three.js`` with the chunks it
                            imports
    cesium.html, cesium/    with ``--cesium CESIUM_DIR`` (npm ``cesium``): CesiumJS's ``Build/Cesium`` and a page
                            (``web/cesium.html``) showing the tileset on the globe with its plain textures
    .neuras-distill-3dtiles marker: this folder is ours, so a later export may replace it
"""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from .. import __version__
from ..errors import BadInputError, require
from .folder_output import check_replaceable, write_folder
from .threejs import PLUGIN, THREE_ENTRIES, three_modules, three_version

MARKER = ".neuras-distill-3dtiles"
PAGE, CESIUM_PAGE = "tiles.html", "cesium.html"
#: ``tiles/tileset.py``'s MARKER (the export room may not import the tiles room, which imports it).
TILESET_MARKER = ".neuras-distill-tileset"
#: What the page and 3DTilesRendererJS's three.js build import from three.js.
TILES_THREE_ENTRIES = (*THREE_ENTRIES, "examples/jsm/utils/BufferGeometryUtils.js")
#: 3DTilesRendererJS's three.js entry point (its package's ``./three`` export).
TILES_ENTRY = "build/index.three.js"


def tiles_renderer_version(tiles_dir: Path) -> str:
    """The version of the 3d-tiles-renderer package at ``tiles_dir``, or BadInputError saying how to get one."""
    hint = "install it with `npm install 3d-tiles-renderer` and pass its node_modules/3d-tiles-renderer folder"
    try:
        meta = json.loads((tiles_dir / "package.json").read_text("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        raise BadInputError(f"--tiles-renderer {tiles_dir} has no readable package.json: {hint}") from None
    require(isinstance(meta, dict) and meta.get("name") == "3d-tiles-renderer",
            f"--tiles-renderer {tiles_dir}: package.json names {meta.get('name')!r}, not 3d-tiles-renderer: {hint}")
    return str(meta.get("version", "unknown"))


def _tileset_files(tileset: Path) -> dict[str, bytes]:
    require((tileset / TILESET_MARKER).is_file() and (tileset / "tileset.json").is_file(),
            f"{tileset} is not a tileset folder of ours (no tileset.json and {TILESET_MARKER}): pass the --out of "
            "`neuras-distill tiles merge`")
    return {f"tileset/{p.relative_to(tileset).as_posix()}": p.read_bytes()
            for p in sorted(tileset.rglob("*")) if p.is_file()}


def cesium_version(cesium_dir: Path) -> str:
    """The version of the cesium package at ``cesium_dir`` (with its ``Build/Cesium``), or BadInputError."""
    hint = "install it with `npm install cesium` and pass its node_modules/cesium folder"
    try:
        meta = json.loads((cesium_dir / "package.json").read_text("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        raise BadInputError(f"--cesium {cesium_dir} has no readable package.json: {hint}") from None
    require(isinstance(meta, dict) and meta.get("name") == "cesium" and
            (cesium_dir / "Build" / "Cesium" / "Cesium.js").is_file(),
            f"--cesium {cesium_dir} is not the cesium package with its Build/Cesium: {hint}")
    return str(meta.get("version", "unknown"))


def tiles_page_files(tileset: Path, three_dir: Path, tiles_dir: Path, cesium_dir: Path | None = None
                     ) -> dict[str, bytes]:
    """{relative path: bytes} of the page folder (module docstring)."""
    versions = {"three": three_version(three_dir), "3d-tiles-renderer": tiles_renderer_version(tiles_dir)}
    if cesium_dir is not None:
        versions["cesium"] = cesium_version(cesium_dir)
    files = _tileset_files(tileset)
    for rel in ("package.json", "LICENSE", *three_modules(three_dir, TILES_THREE_ENTRIES)):
        if (three_dir / rel).is_file():
            files[f"three/{rel}"] = (three_dir / rel).read_bytes()
    for rel in ("package.json", "LICENSE",
                *three_modules(tiles_dir, (TILES_ENTRY,), "--tiles-renderer", "3d-tiles-renderer")):
        if (tiles_dir / rel).is_file():
            files[f"3d-tiles-renderer/{rel}"] = (tiles_dir / rel).read_bytes()
    web = resources.files("neuras_distill") / "web"
    files["index.html"] = (web / PAGE).read_bytes()
    if cesium_dir is not None:
        build = cesium_dir / "Build" / "Cesium"
        for path in sorted(build.rglob("*")):
            if path.is_file() and not path.name.endswith(".map"):
                files[f"cesium/{path.relative_to(build).as_posix()}"] = path.read_bytes()
        files["cesium.html"] = (web / CESIUM_PAGE).read_bytes()
    files[PLUGIN] = (web / PLUGIN).read_bytes()
    files[MARKER] = json.dumps({"generator": "neuras-distill", "version": __version__, **versions}).encode("utf-8")
    return files


def export_3dtiles(tileset, out, three_dir, tiles_dir, cesium_dir=None) -> tuple[Path, dict]:
    """Write the page folder ``out`` for the tileset folder ``tileset`` with three.js from ``three_dir`` and
    3DTilesRendererJS from ``tiles_dir`` (and CesiumJS's page from ``cesium_dir``); everything is checked first and
    the folder appears whole or not at all. Returns (``out``, {package: version})."""
    out, tileset = Path(out), Path(tileset)
    check_replaceable(out, MARKER, "3dtiles page folder")
    files = tiles_page_files(tileset, Path(three_dir), Path(tiles_dir),
                             Path(cesium_dir) if cesium_dir is not None else None)
    meta = json.loads(files[MARKER])
    return write_folder(out, files), {k: meta[k] for k in ("three", "3d-tiles-renderer", "cesium") if k in meta}


__all__ = ["MARKER", "TILESET_MARKER", "cesium_version", "export_3dtiles", "tiles_page_files", "tiles_renderer_version"]
