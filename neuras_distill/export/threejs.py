"""A three.js page of a bundle: ``neuras-distill export BUNDLE --format threejs --three THREE_DIR --out DIR``.

Owns: :func:`export_threejs`, :func:`three_files` and the layout of the folder it writes, a page a three.js
developer can copy: the bundle's ``.glb`` (``export/gltf.py``, with its ``NEURAS_neural_material`` extension)
loaded by three.js's own GLTFLoader with our plugin (``web/neuras-three.js``) beside a three.js grid. Nothing is
fetched from outside the folder: three.js is copied from ``THREE_DIR``, a local ``npm install three``
(``node_modules/three``). Browsers load ES modules only over HTTP: ``python -m http.server`` inside DIR.

Layout of DIR::

    index.html           the page (``web/three.html``): the scene with OrbitControls and three.js's default +Y-up
                         camera (the glb stands upright, ``export/gltf_up.py``); ``?camera=N`` the bundle
                         alone from held-out camera N at its own size (``window.neurasReady`` after the first
                         frame), ``&plain`` the same without the plugin (what other glTF viewers show)
    neuras-three.js      the plugin (package data, copied unchanged)
    scene.glb            ``export --format gltf`` of the bundle
    cameras.json         as the web export's (``export/web.py``): the run's cameras, or a default orbit camera
    three/               from THREE_DIR: package.json, LICENSE, build/three.module.js and the modules it and the
                         page's addons (GLTFLoader, OrbitControls) import, found by following their relative imports
    .neuras-distill-threejs  marker: this folder is ours, so a later export may replace it

Decisions: three.js is copied, not linked, so the folder can be served or moved alone; only the files the page
imports (2.3 MB of three 0.187's 24 MB package). The README names the three.js version CI tests (0.187); another
version is accepted, and its version is printed.
"""

from __future__ import annotations

import json
import re
from importlib import resources
from pathlib import Path

from .. import __version__
from ..errors import BadInputError
from .folder_output import check_replaceable, write_folder
from .texture_limit import DEFAULT_MAX_TEXTURE_SIZE, checked_limit

MARKER = ".neuras-distill-threejs"
PAGE, PLUGIN = "three.html", "neuras-three.js"
#: The modules the page imports from three.js; everything they import relatively is copied with them.
THREE_ENTRIES = ("build/three.module.js", "examples/jsm/loaders/GLTFLoader.js",
                 "examples/jsm/controls/OrbitControls.js")
_RELATIVE_IMPORT = re.compile(r"""(?:\bfrom|\bimport)\s*['"](\.{1,2}/[^'"]+)['"]""")


def three_version(three_dir: Path) -> str:
    """The version of the three.js package at ``three_dir`` (its package.json), or BadInputError saying how to
    get one."""
    hint = "install it with `npm install three` and pass its node_modules/three folder"
    package = three_dir / "package.json"
    if not (three_dir / "build" / "three.module.js").is_file() or not package.is_file():
        raise BadInputError(f"--three {three_dir} is not a three.js package (no build/three.module.js): {hint}")
    try:
        meta = json.loads(package.read_text("utf-8"))
    except (ValueError, UnicodeDecodeError):
        raise BadInputError(f"--three {three_dir}: package.json is not JSON: {hint}") from None
    if not isinstance(meta, dict) or meta.get("name") != "three":
        raise BadInputError(f"--three {three_dir}: package.json names {meta.get('name')!r}, not three: {hint}")
    return str(meta.get("version", "unknown"))


def three_modules(three_dir: Path, entries: tuple[str, ...] = THREE_ENTRIES, flag: str = "--three",
                  package: str = "three") -> list[str]:
    """Paths (relative to ``three_dir``, posix) of ``entries`` and every module they import by a relative path,
    transitively; BadInputError (naming ``flag`` and the npm ``package``) when one is missing."""
    todo, seen = list(entries), set()
    root = three_dir.resolve()
    while todo:
        rel = todo.pop()
        if rel in seen:
            continue
        path = (root / rel).resolve()
        if not path.is_file() or root not in path.parents:
            raise BadInputError(f"{flag} {three_dir}: {rel} is missing (npm install {package} again)")
        seen.add(rel)
        for target in _RELATIVE_IMPORT.findall(path.read_text("utf-8")):
            todo.append((path.parent / target).resolve().relative_to(root).as_posix())
    return sorted(seen)


def three_files(bundle_path: Path, three_dir: Path, max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE,
                up: str = "auto") -> dict[str, bytes]:
    """{relative path: bytes} of the three.js folder (module docstring) for the bundle at ``bundle_path``, its
    glb turned upright by ``up`` (an ``export --up`` value)."""
    from ..bake.bundle import load_bundle, read_bundle_file_bytes
    from ..bake.glb_reader import read_bundle_files
    from .gltf import glb_bytes
    from .gltf_up import parse_up, resolve_up
    from .web import cameras_json

    limit = checked_limit(max_texture_size)
    parse_up(up)
    version = three_version(three_dir)
    modules = three_modules(three_dir)
    bundle = load_bundle(bundle_path)
    if bundle.plain_rgb is None:
        raise BadInputError(f"bundle {bundle_path} has no plain RGB texture (plain_rgb.png; bundles baked by older "
                            "versions lack it): re-run the distillation to export it for three.js")
    raw = read_bundle_files(bundle_path) if bundle_path.is_file() else read_bundle_file_bytes(bundle_path)
    up_vector, _ = resolve_up(up, bundle_path)
    web = resources.files("neuras_distill") / "web"
    files = {"index.html": (web / PAGE).read_bytes(), PLUGIN: (web / PLUGIN).read_bytes(),
             "scene.glb": glb_bytes(bundle, raw, limit, up_vector),
             "cameras.json": cameras_json(bundle, bundle_path.resolve())}
    for rel in ("package.json", "LICENSE", *modules):
        if (three_dir / rel).is_file():
            files[f"three/{rel}"] = (three_dir / rel).read_bytes()
    files[MARKER] = json.dumps({"generator": "neuras-distill", "version": __version__,
                                "three": version}).encode("utf-8")
    return files


def export_threejs(bundle_path, out, three_dir, max_texture_size: int = DEFAULT_MAX_TEXTURE_SIZE,
                   up: str = "auto") -> tuple[Path, str]:
    """Write the three.js folder ``out`` for the bundle at ``bundle_path`` (a folder, or a GLB of ours) with
    three.js copied from ``three_dir``, the glb turned upright by ``up`` (``export --up``). Validates everything
    first, builds the folder under a temporary sibling name and renames it into place (an existing ``out`` is
    replaced only when it carries our marker): on any error nothing is left behind.
    Returns (``out``, the three.js version)."""
    src, out, three_dir = Path(bundle_path), Path(out), Path(three_dir)
    check_replaceable(out, MARKER, "three.js folder")
    if not src.exists():
        raise BadInputError(f"bundle {src} does not exist")
    files = three_files(src, three_dir, max_texture_size, up)
    return write_folder(out, files), json.loads(files[MARKER])["three"]


__all__ = ["MARKER", "THREE_ENTRIES", "export_threejs", "three_files", "three_modules", "three_version"]
