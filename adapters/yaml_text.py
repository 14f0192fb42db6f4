"""Reading YAML safely: the one module that imports PyYAML (for the adapters' config files).

This module owns :func:`load_yaml`: ``yaml.SafeLoader`` (plain data only), optionally extended so that the
``!!python/...`` tags PyYAML's default dumper writes (nerfstudio's ``config.yml`` is a ``yaml.dump`` of its config
dataclasses) are read **as data**: nothing is imported, constructed or called, whatever the tag names.

* ``!!python/object:X`` / ``!!python/object/new:X`` (a mapping) -> ``{"_type": "X", ...the mapping}``;
* ``!!python/object/apply:X`` (a sequence or mapping of arguments) -> ``{"_apply": "X", "args": [...]}``
  (``pathlib.PosixPath`` / ``WindowsPath`` become the joined path string, ``None`` arguments -> ``""``);
* ``!!python/name:X`` / ``!!python/module:X`` -> the string ``"X"``; ``!!python/tuple`` -> a list;
  other ``!!python/<scalar type>`` tags -> the scalar's text.

Everything stays data: ``!!python/object/apply:os.system ["rm -rf ~"]`` reads as
``{"_apply": "os.system", "args": ["rm -rf ~"]}`` and is never executed.
"""

from __future__ import annotations

from typing import Any

import yaml

from neuras_distill.errors import BadInputError

_PYTHON = "tag:yaml.org,2002:python/"
_PATHS = ("pathlib.PosixPath", "pathlib.WindowsPath", "pathlib.Path", "pathlib.PurePosixPath")


class _PythonTagsAsData(yaml.SafeLoader):
    """SafeLoader that reads ``!!python/...`` tags as plain data (module docstring)."""


def _python_tag(loader: _PythonTagsAsData, suffix: str, node: yaml.Node) -> Any:
    kind, _, name = suffix.partition(":")
    if kind in ("object", "object/new"):
        data = loader.construct_mapping(node, deep=True) if isinstance(node, yaml.MappingNode) else {
            "args": loader.construct_sequence(node, deep=True) if isinstance(node, yaml.SequenceNode)
            else loader.construct_scalar(node)}
        return {"_type": name, **{str(k): v for k, v in data.items()}}
    if kind == "object/apply":
        if isinstance(node, yaml.SequenceNode):
            args = loader.construct_sequence(node, deep=True)
        elif isinstance(node, yaml.MappingNode):
            args = loader.construct_mapping(node, deep=True).get("args", [])
        else:
            args = [loader.construct_scalar(node)]
        if name in _PATHS:
            return "/".join("" if a is None else str(a) for a in args) or "."
        return {"_apply": name, "args": list(args)}
    if kind in ("name", "module"):
        return name
    if kind == "tuple":
        return loader.construct_sequence(node, deep=True)
    if isinstance(node, yaml.ScalarNode):
        return loader.construct_scalar(node)
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_mapping(node, deep=True)


_PythonTagsAsData.add_multi_constructor(_PYTHON, _python_tag)


def load_yaml(text: str, source: str, *, python_tags: bool = False) -> Any:
    """The data in ``text`` (YAML), or :class:`BadInputError` naming ``source`` and the first parse error.

    ``python_tags``: read ``!!python/...`` tags as data (module docstring) instead of refusing them."""
    try:
        return yaml.load(text, Loader=_PythonTagsAsData if python_tags else yaml.SafeLoader)  # noqa: S506
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise BadInputError(f"{source} is not valid YAML: {first}") from None
