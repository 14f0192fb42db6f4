"""The package's import graph, read from the source (ast): no module imports itself through others, and no room
(a subpackage or a top-level module) imports a room that imports it back. Imports inside functions count: a
lazy import is still a dependency, and a cycle through one is a layering mistake waiting for a refactor."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "neuras_distill"
DOC = ROOT / "docs" / "architecture.md"
START, END = "<!-- room-table:start -->", "<!-- room-table:end -->"

#: Which rooms each room may import (docs/architecture.md's table is generated from this: ``python
#: tests/test_import_graph.py``). A room is a subpackage of ``neuras_distill`` or one of its top-level modules
#: (``neuras_distill`` itself: the package's ``__init__``), and ``adapters`` (every format's package). The test
#: holds the code to it exactly: a new import between rooms is a decision, written here and so in the doc.
ROOMS = {
    "errors": set(),
    "flip_metric": set(),
    "logs": set(),
    "cli_parser": set(),
    "neuras_distill": set(),
    "device": {"errors"},
    "fields": {"errors"},
    "registry": {"errors"},
    "metrics": {"flip_metric"},
    "components": {"device", "errors"},
    "precision": {"components", "device", "errors"},
    "config": {"errors", "precision"},
    "device_field": {"device", "precision"},
    "render": {"config", "device", "errors", "logs"},
    "neural": {"config", "errors"},
    "geometry": {"config", "errors", "fields", "logs", "render"},
    "scenes": {"config", "errors", "fields", "geometry", "render"},
    "bake": {"errors", "geometry"},
    "playback": {"bake", "errors", "geometry", "logs", "render"},
    "export": {"bake", "errors", "neuras_distill", "playback", "render"},
    "run_inputs": {"config", "errors", "registry", "render", "scenes"},
    "stability": {"config", "errors", "fields", "playback", "registry", "render", "run_inputs", "scenes"},
    "pipeline": {"bake", "config", "device", "device_field", "errors", "export", "fields", "flip_metric", "geometry",
                 "logs", "metrics", "neural", "neuras_distill", "playback", "render", "stability"},
    "path_video": {"bench", "errors", "export", "playback", "render"},
    "bench": {"bake", "cli_parser", "config", "errors", "fields", "flip_metric", "logs", "metrics", "neuras_distill",
              "pipeline", "playback", "render", "run_inputs"},
    "tiles": {"bake", "config", "errors", "export", "geometry", "logs", "neuras_distill", "pipeline", "playback",
              "render", "stability"},
    "cli": {"bake", "bench", "cli_parser", "config", "device", "errors", "export", "logs", "path_video", "pipeline",
            "playback", "run_inputs", "scenes", "stability", "tiles"},
    "adapters": {"components", "errors", "fields", "render", "scenes"},
}


def module_names() -> dict[str, Path]:
    """{dotted module name: file} of every module of the package and of ``adapters/`` (a package is its
    ``__init__``)."""
    names = {}
    for path in [*PACKAGE.rglob("*.py"), *(ROOT / "adapters").rglob("*.py")]:
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names[".".join(parts)] = path
    return names


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The package's modules that ``name`` imports anywhere in its source (module level or inside functions)."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()
    for node in ast.walk(ast.parse(path.read_text("utf-8"))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            targets = [f"{module}.{alias.name}" for alias in node.names] + [module]
        else:
            continue
        for target in targets:
            while target and target not in modules:          # a name imported from a module: that module
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def module_graph() -> dict[str, set[str]]:
    modules = module_names()
    return {name: imports_of(name, path, modules) for name, path in modules.items()}


def room(name: str) -> str:
    """``neuras_distill.bake.bundle`` -> ``bake``; a top-level module is its own room; ``neuras_distill`` is the
    package's ``__init__``; every module under ``adapters/`` is ``adapters``."""
    parts = name.split(".")
    if parts[0] == "adapters":
        return "adapters"
    return parts[1] if len(parts) > 1 else parts[0]


def room_graph() -> dict[str, set[str]]:
    """{room: the other rooms its modules import}."""
    rooms: dict[str, set[str]] = {}
    for name, targets in module_graph().items():
        rooms.setdefault(room(name), set()).update(room(t) for t in targets if room(t) != room(name))
    return rooms


def room_table() -> str:
    """The markdown table of :data:`ROOMS` that docs/architecture.md holds between its room-table markers."""
    rows = ["| room | may import |", "|---|---|"]
    for name in sorted(ROOMS, key=lambda r: (len(ROOMS[r]), r)):
        allowed = ", ".join(f"`{r}`" for r in sorted(ROOMS[name])) or "nothing of the package"
        rows.append(f"| `{name}` | {allowed} |")
    return "\n".join(rows)


def test_the_cycle_finder_finds_a_cycle_and_passes_a_chain():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": set()}) == []


def test_the_graph_sees_lazy_and_relative_imports():
    graph = module_graph()
    assert "neuras_distill.pipeline.run" in graph["neuras_distill.cli"]                 # inside a function
    assert "neuras_distill.bake.bundle" in graph["neuras_distill.playback.renderer"]     # ``from ..bake.bundle``
    assert "neuras_distill.errors" in graph["adapters.nerfstudio.field"]                 # the adapters too
    assert len(graph) > 100


def test_no_module_imports_itself_through_others():
    assert cycles(module_graph()) == []


def test_no_room_imports_a_room_that_imports_it():
    assert cycles(room_graph()) == []


def test_every_room_imports_what_the_room_table_allows():
    rooms = room_graph()
    assert set(rooms) == set(ROOMS), (sorted(set(rooms) - set(ROOMS)), sorted(set(ROOMS) - set(rooms)))
    unlisted = {r: sorted(rooms[r] - ROOMS[r]) for r in rooms if rooms[r] - ROOMS[r]}
    unused = {r: sorted(ROOMS[r] - rooms[r]) for r in rooms if ROOMS[r] - rooms[r]}
    assert not unlisted, f"imports the room table does not allow (add them to ROOMS if meant): {unlisted}"
    assert not unused, f"the room table allows imports no module makes (remove them from ROOMS): {unused}"
    assert cycles(ROOMS) == []


def test_the_architecture_doc_holds_the_room_table():
    text = DOC.read_text()
    assert START in text and END in text
    held = text.split(START, 1)[1].split(END, 1)[0].strip()
    assert held == room_table(), "docs/architecture.md's room table is stale: run python tests/test_import_graph.py"


def write_room_table() -> None:
    """Write :func:`room_table` into docs/architecture.md between its markers."""
    text = DOC.read_text()
    head, rest = text.split(START, 1)
    DOC.write_text(head + START + "\n" + room_table() + "\n" + END + rest.split(END, 1)[1])


if __name__ == "__main__":
    write_room_table()
    print(f"wrote the room table into {DOC}")
