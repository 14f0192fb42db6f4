"""pyproject.toml lists the packages by hand (adapters/ and configs/ are mapped to other names): every package
folder of neuras_distill and of adapters/ (installed as neuras_distill_adapters) must be in that list, or an
installed (non-editable) copy silently lacks it."""

try:
    import tomllib
except ModuleNotFoundError:      # Python 3.10
    import tomli as tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SETUPTOOLS = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def _package_names(top: str) -> set[str]:
    """Dotted names of the package folders under the folder that ``package-dir`` maps ``top`` to."""
    folder = ROOT / SETUPTOOLS["package-dir"][top]
    return {".".join((top,) + p.parent.relative_to(folder).parts) for p in folder.rglob("__init__.py")
            if "__pycache__" not in p.parts}


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(SETUPTOOLS["packages"])
    for top in ("neuras_distill", "neuras_distill_adapters"):
        folders = _package_names(top)
        assert top in folders
        missing = sorted(folders - listed)
        assert not missing, f"package folders missing from pyproject.toml [tool.setuptools] packages: {missing}"


def test_adapter_entry_points_name_listed_packages():
    """Each shipped adapter's entry point names a module that exists and whose package is listed."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    listed = set(SETUPTOOLS["packages"])
    for name, target in project["entry-points"]["neuras_distill.adapters"].items():
        top, *rest = target.split(":")[0].split(".")
        path = ROOT / SETUPTOOLS["package-dir"][top] / Path(*rest) if rest else ROOT / SETUPTOOLS["package-dir"][top]
        if (path / "__init__.py").is_file():
            package = target.split(":")[0]
        else:
            assert path.with_suffix(".py").is_file(), f"entry point {name} = {target}: no such module"
            package = target.split(":")[0].rpartition(".")[0]
        assert package in listed, f"entry point {name} = {target}: package {package} is not in pyproject's list"


def test_every_data_file_of_the_package_is_listed_and_it_is_typed():
    """Package data is listed file by file (no globs that would ship strays): every file of neuras_distill that is
    not Python is in the list, and the list names nothing that is missing; ``py.typed`` ships (PEP 561)."""
    data = SETUPTOOLS["package-data"]["neuras_distill"]
    package = ROOT / "neuras_distill"
    shipped = {p.relative_to(package).as_posix() for p in package.rglob("*")
               if p.is_file() and p.suffix not in (".py", ".pyc") and "__pycache__" not in p.parts}
    assert "py.typed" in data
    assert shipped == set(data), (sorted(shipped - set(data)), sorted(set(data) - shipped))
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT" and "Typing :: Typed" in project["classifiers"]
