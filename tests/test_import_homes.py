"""Each wrapped third-party library is imported in exactly one module (docs/architecture.md, first rule).

The check reads the source (``ast``), so lazy imports inside functions count as well as top-level ones.
numpy, torch, scipy, PIL and tqdm are the common vocabulary of the package and are not wrapped.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: library (top-level import name) -> the one module (path from the repository root) allowed to import it
HOMES = {
    "igl": "neuras_distill/geometry/raycast.py",
    "av": "neuras_distill/export/video.py",
    "pyproj": "neuras_distill/tiles/crs.py",
    "ray": "neuras_distill/tiles/ray_jobs.py",
    "moderngl": "neuras_distill/playback/context.py",
    "pymeshlab": "neuras_distill/geometry/cleanup.py",
    "xatlas": "neuras_distill/geometry/unwrap.py",
    "skimage": "neuras_distill/geometry/lattice_mc.py",
    "glfw": "neuras_distill/playback/window.py",
    "flip_evaluator": "neuras_distill/flip_metric.py",
    "matplotlib": "neuras_distill/pipeline/report.py",
    "msgpack": "adapters/instant_ngp/snapshot.py",
    "yaml": "adapters/yaml_text.py",
}


def importers() -> dict[str, set[str]]:
    """Top-level import name -> the package modules (paths from the repository root) importing it anywhere."""
    found: dict[str, set[str]] = {}
    for folder in ("neuras_distill", "adapters"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    found.setdefault(name.split(".")[0], set()).add(path.relative_to(ROOT).as_posix())
    return found


@pytest.mark.parametrize("library", sorted(HOMES))
def test_library_has_one_home(library):
    assert importers().get(library, set()) == {HOMES[library]}


def test_trimesh_is_not_imported_by_the_package():
    """trimesh is a test dependency only (glTF round trips); the package must not need it."""
    assert "trimesh" not in importers()


def test_the_scan_sees_imports_inside_functions():
    """The scan is not blind to lazy imports: xatlas and moderngl are imported only inside functions."""
    found = importers()
    assert found["xatlas"] == {"neuras_distill/geometry/unwrap.py"}
    assert found["moderngl"] == {"neuras_distill/playback/context.py"}
