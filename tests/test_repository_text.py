"""The repository's text: no development bookkeeping in tracked files, no references to files outside the
repository, generated docs equal to their generators' output, and a README whose commands are the ones CI runs."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Upstream projects whose public trackers a line may cite ("nerfstudio #2068", "instant-ngp ... issue #1577").
UPSTREAM = re.compile(r"nerfstudio|instant-ngp|NVlabs|tiny-cuda-nn|xatlas|pymeshlab|meshlab|trimesh|gsplat"
                      r"|nerfacc|pytorch3d|kaolin|nerf2mesh|instant-nsr-pl|moderngl|glfw"
                      r"|[\w-]+/[\w.-]+ (?:PR|issue)", re.IGNORECASE)

#: (name, pattern, which files, lines that are allowed despite matching). Each pattern is development bookkeeping:
#: rounds of work, our own tracker's numbers, scratch paths, borrowed machines, files outside the repository.
RULES = [
    ("development round", re.compile(r"\bsess" r"ions?\b", re.IGNORECASE), "all",
     re.compile(r"""scope=["']session["']|session-scoped|pytest_session\w*\(session""")),
    ("tracker issue number", re.compile(r"\bissues?[ -]#?[0-9]+", re.IGNORECASE), "all", None),
    ("scratch folder", re.compile(r"\.dev[0-9]+/"), "all", None),
    ("temporary path", re.compile(r"/tmp/"), "docs", None),
    ("borrowed machine", re.compile(r"\blent\b|\bborrowed\b", re.IGNORECASE), "all", None),
    ("file outside the repository", re.compile(r"DESIGN\.md|docs/report\.md"), "all", None),
    ("round of work", re.compile(r"\b(?:round|rounds) of (?:work|development)\b", re.IGNORECASE), "all", None),
]

#: This file names the patterns it looks for.
SELF = "tests/test_repository_text.py"


def tracked_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, timeout=60)
    except (OSError, subprocess.CalledProcessError) as exc:
        pytest.skip(f"not a git checkout: {exc}")
    return [p for p in out.stdout.decode().split("\0") if p and (ROOT / p).is_file()]


def _is_doc(path: str) -> bool:
    return path.endswith(".md") or path.startswith("docs/")


def bookkeeping_lines(files: list[str]) -> list[str]:
    """Every line of ``files`` (paths relative to the repository) that matches a rule, as
    ``path:line: [rule] text``."""
    found = []
    for path in files:
        if path == SELF:
            continue
        try:
            text = (ROOT / path).read_text(encoding="utf-8")
        except (UnicodeDecodeError, OSError):
            continue                                        # binary files (checkpoints, images)
        for number, line in enumerate(text.splitlines(), 1):
            for name, pattern, where, allowed in RULES:
                if where == "docs" and not _is_doc(path):
                    continue
                match = pattern.search(line)
                if not match or (allowed is not None and allowed.search(line)):
                    continue
                if name == "tracker issue number" and UPSTREAM.search(line[:match.start()]):
                    continue
                found.append(f"{path}:{number}: [{name}] {line.strip()[:160]}")
    return found


def test_no_development_bookkeeping_in_tracked_files():
    found = bookkeeping_lines(tracked_files())
    assert not found, ("development bookkeeping in tracked files (say the current fact instead):\n"
                       + "\n".join(found))


def test_the_bookkeeping_patterns_catch_what_they_should(tmp_path, monkeypatch):
    """The rules fire on bookkeeping and stay quiet on pytest's fixture scopes and upstream trackers' numbers.
    The bad examples are split literals, so that the tree itself holds none of them."""
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    bad = {"a.py": "# measured in sess" "ion 24 on the lent H200\n",
           "b.py": '"""Atlas pages (iss' 'ue 15)."""\nx = 1  # see issue #7\n',
           "c.md": "probe: `.dev" "24/probe2.py`, output in /tmp/run\n",
           "d.py": "# the contract is DESIGN.md §2\n",
           "h.py": "# torch is slower here (iss" "ue 12)\n"}
    good = {"e.py": '@pytest.fixture(scope="session")\ndef pytest_sessionfinish(session, exitstatus):\n',
            "f.py": "# nerfstudio #2068 is this bug; NVlabs/instant-ngp PR #1192 and issue #1577\n",
            "g.py": "out = Path('/tmp/x')  # scratch paths in code are not docs\n"}
    for name, text in {**bad, **good}.items():
        (tmp_path / name).write_text(text)
    found = bookkeeping_lines(sorted(bad) + sorted(good))
    assert [f.split(": [")[0] for f in found] == ["a.py:1", "a.py:1", "b.py:1", "b.py:2", "c.md:1", "c.md:1",
                                                  "d.py:1", "h.py:1"], found


def test_references_to_decisions_name_an_entry():
    """Every ``docs/decisions.md "Title"`` in the tree names an entry of docs/decisions.md (a bold title that
    starts with it)."""
    decisions = (ROOT / "docs" / "decisions.md").read_text()
    titles = re.findall(r"^- \*\*(.+?)\*\*", decisions, flags=re.MULTILINE)
    assert len(titles) >= 30
    missing = []
    for path in tracked_files():
        if not path.endswith((".py", ".md", ".toml")) or path == SELF:
            continue
        text = (ROOT / path).read_text(encoding="utf-8")
        for ref in re.findall(r'decisions\.md,? "([^"]+)"', text.replace("\n#", " ").replace("\n", " ")):
            if not any(t.startswith(ref) for t in titles):
                missing.append(f"{path}: {ref!r}")
    assert not missing, "references to docs/decisions.md entries that do not exist:\n" + "\n".join(missing)


def test_configuration_reference_is_generated_from_config():
    import importlib.util

    spec = importlib.util.spec_from_file_location("config_reference", ROOT / "scripts" / "config_reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    text = module.render()
    from neuras_distill.config import DistillConfig

    cfg = DistillConfig()
    for section in ("cameras", "teacher", "geometry", "texture", "train", "eval", "skybox"):
        for name in vars(getattr(cfg, section)):
            assert f"**`{section}.{name}`**" in text, f"{section}.{name} is missing from the reference"
    assert "**`texture.hidden`** (int, default `32`)" in text
    assert (ROOT / "docs" / "configuration.md").read_text() == text, (
        "docs/configuration.md is out of date: run python scripts/config_reference.py")


def _readme() -> str:
    return (ROOT / "README.md").read_text()


def test_readme_starts_with_the_install_demo_and_test_commands_ci_runs():
    readme = _readme()
    first_block = re.search(r"```bash\n(.*?)```", readme, flags=re.DOTALL)
    assert first_block and readme.index("```bash") < 200, "the README must open with its commands"
    commands = [ln for ln in first_block.group(1).splitlines() if ln and not ln.startswith("#")]
    assert commands == ["bash scripts/setup.sh && .venv/bin/neuras-distill demo",
                        "bash scripts/setup.sh && .venv/bin/python -m pytest"]
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln.strip() and
          not ln.lstrip().startswith("#")]
    setup, test = commands[1].split(" && ")
    assert ci[-1] == test and setup in ci, "CI must run the README's test command"
    assert ci[ci.index(setup) + 1:-1] == [".venv/bin/ruff check neuras_distill adapters"], (
        "CI lints the package with ruff between setup and the tests")


def test_readme_is_short_and_its_results_come_from_results_md():
    readme = _readme()
    assert len(readme.splitlines()) <= 250
    results = (ROOT / "docs" / "results.md").read_text().splitlines()
    header = next(ln for ln in results if ln.startswith("| scene |"))
    lines = readme.splitlines()
    assert lines.count(header) == 1, "the README's results table has docs/results.md's header"
    start = lines.index(header) + 2
    rows = lines[start:lines.index("", start)]
    assert len(rows) >= 4 and all(r.startswith("| `") for r in rows)
    assert all(r in results for r in rows), [r for r in rows if r not in results]
    for command in ("demo", "from-synthetic", "from-ngp", "from-nerfstudio", "from-sdf", "check", "view", "export",
                    "bench"):
        assert re.search(rf"^neuras-distill {command} ", readme, flags=re.MULTILINE), command
    assert "adapters/" in readme and "nerfstudio/" in readme


def test_readme_own_field_example_is_a_valid_field(monkeypatch):
    """The README's "write your own field" block runs as written (``distill`` replaced by the contract check, so
    no pipeline runs here) and its field passes ``check_field``."""
    import neuras_distill as nd
    from neuras_distill.fields.base import check_field

    block = next(b for b in re.findall(r"```python\n(.*?)```", _readme(), flags=re.DOTALL) if "class " in b)
    calls = []

    def fake_distill(field, cameras, config=None, out=None, **kw):
        check_field(field)
        calls.append((field, cameras, config, out))

    monkeypatch.setattr(nd, "distill", fake_distill, raising=False)
    exec(compile(block, "README.md", "exec"), {"__name__": "__main__"})
    (field, cameras, config, out), = calls
    assert field.kind == "sdf" and len(cameras) == 24 and cameras.width == 256
    assert isinstance(config, nd.DistillConfig) and config.train.steps == nd.load_config("fast").train.steps
    import torch

    x = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.1]])
    assert torch.allclose(field.geometry(x), torch.tensor([-1.0, 0.0, 0.1]), atol=1e-6)
