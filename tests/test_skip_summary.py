"""The line pytest prints after its summary when tests of real clients were skipped for a missing tool."""

from __future__ import annotations

from types import SimpleNamespace

from real_clients import INSTALL_CLIENTS, missing_tool_skips


def _skipped(reason: str):
    return SimpleNamespace(longrepr=("tests/test_x.py", 3, f"Skipped: {reason}"))


def test_only_missing_tools_are_counted_and_the_install_command_names_every_client():
    reports = [_skipped("/usr/bin/chromium is absent (apt-get install chromium chromium-driver; .ci/run does)"),
               _skipped("xvfb-run is not installed (apt-get install xvfb xauth); the window tests need it"),
               _skipped("this GL does not report GL_MAX_ARRAY_TEXTURE_LAYERS"),
               _skipped("not a git checkout: no .git")]
    reasons = missing_tool_skips(reports)
    assert len(reasons) == 2 and reasons[0].startswith("/usr/bin/chromium is absent")
    for package in ("chromium", "chromium-driver", "blender", "xvfb", "nodejs", "npm"):
        assert package in INSTALL_CLIENTS.split()
