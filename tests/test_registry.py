"""The adapter registry (neuras_distill.registry) with faked entry points: each plug-in is loaded once per
process, a broken one is skipped and named when asked for, sniffing picks by content."""

from __future__ import annotations

import pytest

from neuras_distill import registry
from neuras_distill.errors import BadInputError


class FakeEntryPoint:
    """Stands in for an ``importlib.metadata.EntryPoint``: ``load()`` returns ``target`` or raises it, and
    counts its calls in ``loads`` (shared by all fakes)."""

    def __init__(self, name, target, loads):
        self.name, self.target, self.loads = name, target, loads

    def load(self):
        self.loads[self.name] = self.loads.get(self.name, 0) + 1
        if isinstance(self.target, BaseException):
            raise self.target
        return self.target


class TextAdapter:
    """Reads files starting with ``TEXT``; the field it returns is just the file's text."""

    name = "text"

    def sniff(self, path):
        return path.read_bytes()[:4] == b"TEXT"

    def load(self, path, **options):
        return ("text field", path.read_text(), options)


class NeverAdapter:
    name = "never"

    def sniff(self, path):
        return False

    def load(self, path, **options):
        raise AssertionError("never sniffs, never loads")


@pytest.fixture
def fake_plugins(monkeypatch):
    """Three entry points (two good, one whose module fails to import); yields the load counts."""
    loads: dict = {}
    eps = [FakeEntryPoint("never", NeverAdapter, loads), FakeEntryPoint("text", TextAdapter, loads),
           FakeEntryPoint("shiny", ModuleNotFoundError("No module named 'shiny_dep'"), loads)]
    scans = []

    def fake_entry_points(group):
        scans.append(group)
        return eps

    monkeypatch.setattr(registry, "entry_points", fake_entry_points)
    registry.reload_adapters()
    yield loads, scans
    registry.reload_adapters()        # the next test sees the real entry points again


def test_plugins_are_loaded_once_per_process(fake_plugins, tmp_path):
    loads, scans = fake_plugins
    ckpt = tmp_path / "a.ckpt"
    ckpt.write_text("TEXT hello")
    for _ in range(3):
        assert set(registry.available_adapters()) == {"never", "text"}
        assert set(registry.broken_adapters()) == {"shiny"}
        assert registry.load_field(ckpt)[:2] == ("text field", "TEXT hello")
        assert registry.load_field(ckpt, adapter="text", level=2)[2] == {"level": 2}
        with pytest.raises(BadInputError, match="shiny"):
            registry.load_field(ckpt, adapter="shiny")
    assert loads == {"never": 1, "text": 1, "shiny": 1}
    assert scans == [registry.GROUP]
    registry.reload_adapters()                                   # forgetting the cache loads them again
    registry.available_adapters()
    assert loads == {"never": 2, "text": 2, "shiny": 2} and len(scans) == 2


def test_a_broken_plugin_is_skipped_and_named_when_asked_for(fake_plugins, tmp_path):
    ckpt = tmp_path / "a.ckpt"
    ckpt.write_text("TEXT hello")
    assert "shiny" not in registry.available_adapters()
    assert registry.broken_adapters() == {"shiny": "ModuleNotFoundError: No module named 'shiny_dep'"}
    assert registry.load_field(ckpt)[0] == "text field"        # the others still work
    with pytest.raises(BadInputError, match=r"adapter 'shiny' is installed but fails to import "
                                            r"\(ModuleNotFoundError: No module named 'shiny_dep'\)"):
        registry.load_field(ckpt, adapter="shiny")
    with pytest.raises(BadInputError, match="unknown adapter 'nope'; installed: never, text"):
        registry.load_field(ckpt, adapter="nope")


def test_callers_cannot_change_the_cache(fake_plugins):
    registry.available_adapters().clear()
    registry.broken_adapters().clear()
    assert set(registry.available_adapters()) == {"never", "text"}
    assert set(registry.broken_adapters()) == {"shiny"}


def test_nothing_sniffs_it(fake_plugins, tmp_path):
    other = tmp_path / "b.bin"
    other.write_bytes(b"\x00\x01")
    with pytest.raises(BadInputError,
                       match=r"not a checkpoint any installed adapter reads \(tried: never, text\)"):
        registry.load_field(other)


def test_the_real_entry_points_are_installed():
    registry.reload_adapters()
    assert {"synthetic", "instant_ngp", "neus"} <= set(registry.available_adapters())
    assert registry.broken_adapters() == {}
