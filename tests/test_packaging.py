"""pyproject.toml lists the packages by hand (adapters/ and configs/ are mapped to other names): every package
folder of neuras_distill must be in that list, or an installed (non-editable) copy silently lacks it."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {".".join(p.parent.relative_to(ROOT).parts) for p in (ROOT / "neuras_distill").rglob("__init__.py")}
    missing = sorted(folders - listed)
    assert not missing, f"package folders missing from pyproject.toml [tool.setuptools] packages: {missing}"
