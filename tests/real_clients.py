"""What the tests that drive real clients (Chromium, Blender, xvfb, node, OpenGL) say when their tool is missing:
the words that mark such a skip and the command that installs every client (``conftest.pytest_terminal_summary``)."""

from __future__ import annotations


#: Words in a skip reason that say an outside tool (a real client the tests drive) is missing.
MISSING_TOOL_WORDS = ("apt-get install", "npm", ".tools/", "no OpenGL", "no node")
#: What installs every real client on Debian/Ubuntu (what ``.ci/run`` does before the tests).
INSTALL_CLIENTS = ("sudo apt-get install chromium chromium-driver blender python3-numpy xvfb xauth nodejs npm "
                   "&& bash scripts/setup.sh")


def missing_tool_skips(skipped) -> list[str]:
    """The skip reasons, among the ``skipped`` test reports, that name a missing outside tool."""
    reasons = []
    for report in skipped:
        longrepr = getattr(report, "longrepr", None)
        reason = str(longrepr[2] if isinstance(longrepr, tuple) and len(longrepr) == 3 else longrepr or "")
        if any(word in reason for word in MISSING_TOOL_WORDS):
            reasons.append(reason.removeprefix("Skipped: "))
    return reasons
