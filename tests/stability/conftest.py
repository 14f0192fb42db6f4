"""The stability catalogue's machinery: every case carries ``@pytest.mark.stability(case=..., family=...,
reference=..., tolerance=...)``; with ``STABILITY_RECORD=path.json`` in the environment, each case's record
and its result (passed / failed / xfailed / skipped, seconds) are written there for
``scripts/stability_table.py``, which turns them into docs/stability.md's table.

Every test runs with one torch thread (the shared CPU; and small tensors are faster on one).
"""

from __future__ import annotations

import json
import os

import pytest

_RESULTS: list[dict] = []


def pytest_configure(config):
    config.addinivalue_line("markers", "stability(case, family, reference, tolerance): a stability catalogue case")


@pytest.fixture(autouse=True)
def _one_thread():
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


def pytest_collection_modifyitems(config, items):
    for item in items:
        if "tests/stability" in str(item.fspath).replace(os.sep, "/") and item.get_closest_marker("stability") is None:
            raise pytest.UsageError(f"{item.nodeid} has no @pytest.mark.stability(...) record")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    rep = outcome.get_result()
    mark = item.get_closest_marker("stability")
    if mark is None:
        return
    if rep.when == "call" or (rep.when == "setup" and rep.outcome != "passed"):
        if hasattr(rep, "wasxfail"):
            result = "xfailed" if rep.skipped else "xpassed"
        else:
            result = rep.outcome
        rec = dict(mark.kwargs)
        param = item.callspec.id if hasattr(item, "callspec") else ""
        rec.update(nodeid=item.nodeid, param=param, result=result, seconds=round(rep.duration, 3),
                   module=item.module.__name__.rsplit(".", 1)[-1])
        xf = item.get_closest_marker("xfail")
        if xf is not None:
            rec["xfail_reason"] = xf.kwargs.get("reason", "")
        _RESULTS.append(rec)


def pytest_sessionfinish(session, exitstatus):
    path = os.environ.get("STABILITY_RECORD")
    if path and _RESULTS:
        with open(path, "w") as fh:
            json.dump(_RESULTS, fh, indent=1)
