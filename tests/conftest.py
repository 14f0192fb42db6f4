"""Shared test helpers."""

from __future__ import annotations

import contextlib
import os
import shutil
from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


def require_gl() -> None:
    """Skip the calling test when no headless OpenGL (EGL) context can be made here; with ``CI=true`` in the
    environment (``.ci/run`` sets it) fail it instead, so CI cannot pass by silently skipping every GL test.
    Tests needing GL carry ``@pytest.mark.gl``; :func:`pytest_runtest_setup` calls this before their fixtures."""
    from neuras_distill.playback.context import gl_available

    ok, reason = gl_available()
    if ok:
        return
    message = f"no OpenGL context: {reason}"
    if os.environ.get("CI") == "true":
        pytest.fail(f"{message} (CI=true: the GL tests must run in CI)", pytrace=False)
    pytest.skip(message)


def _require_tool(missing: str | None) -> None:
    """Skip the calling test when an outside tool it drives is absent (``missing`` says which and how to install
    it; None: present); with ``CI=true`` fail it instead: ``.ci/run`` installs every tool, so CI cannot pass by
    skipping what it should have checked."""
    if missing is None:
        return
    if os.environ.get("CI") == "true":
        pytest.fail(f"{missing} (CI=true: .ci/run installs it, the test must run in CI)", pytrace=False)
    pytest.skip(missing)


@pytest.fixture(scope="session")
def require_tool():
    """:func:`_require_tool` for tests: ``require_tool(None if found else "X is absent (apt-get install x)")``."""
    return _require_tool


CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


def browser_missing() -> str | None:
    """What is missing for the browser tests (selenium, Debian's chromium and chromedriver), or None."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    for path in (CHROMIUM, CHROMEDRIVER):
        if not Path(path).exists():
            return f"{path} is absent (apt-get install chromium chromium-driver; .ci/run does)"
    return None


@pytest.fixture
def browser(chromium_session):
    """The shared headless Chromium for one test, left on a blank page after it: a player page left open keeps
    drawing frames on SwiftShader (requestAnimationFrame), and took a core from every test after it (the resume
    tests ran 2.3x slower in the suite than alone)."""
    try:
        yield chromium_session
    finally:
        chromium_session.get("about:blank")


@pytest.fixture(scope="session")
def chromium_session():
    """One headless Chromium (the system's, through selenium and the system chromedriver; WebGL2 on
    SwiftShader) for every browser test of the run; skipped without it (failed under ``CI=true``)."""
    _require_tool(browser_missing())
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--disable-extensions",
                "--force-device-scale-factor=1", "--window-size=800,600"):
        opts.add_argument(arg)
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="session")
def http_root(tmp_path_factory):
    """(folder, base URL): a local HTTP server over a fresh folder, for pages that fetch (modules, data)."""
    import functools
    import threading
    from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

    root = tmp_path_factory.mktemp("site")

    class Quiet(SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    httpd = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(root)))
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield root, f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()
        httpd.server_close()


#: Fixtures that run a whole distillation (or more): a test using one is marked ``slow`` whether it says so or not,
#: so the development loop ``pytest -m "not slow"`` never waits for one.
DISTILLING_FIXTURES = frozenset({"small_run", "sky_run"})


#: Under pytest-xdist (``-n 2``, the default addopts) each worker process gets one torch thread, so two workers
#: share the 2 cores without oversubscribing them; the processes a test starts inherit it (OMP_NUM_THREADS).
WORKER_THREADS = 1 if os.environ.get("PYTEST_XDIST_WORKER") else None
if WORKER_THREADS is not None:
    os.environ["OMP_NUM_THREADS"] = str(WORKER_THREADS)
    os.environ["MKL_NUM_THREADS"] = str(WORKER_THREADS)


def pytest_configure(config):
    if WORKER_THREADS is not None:
        import torch

        torch.set_num_threads(WORKER_THREADS)


def _shared_fixture_group(item) -> str | None:
    """The ``xdist_group`` of a test that uses an expensive shared fixture: "shared-distillations" for the
    distilling fixtures (built once for the whole run), its file for a module- or run-wide fixture defined in
    that file; None when every fixture it uses is per test or a conftest's cheap one (built once per worker)."""
    defs = getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {})
    if DISTILLING_FIXTURES & set(getattr(item, "fixturenames", ())):
        return "shared-distillations"
    own_file = item.nodeid.split("::")[0]
    if any(d.scope != "function" and d.baseid == own_file for fixture_defs in defs.values() for d in fixture_defs):
        return own_file
    return None


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Marks the users of a distilling fixture ``slow``. Gives each test that shares an expensive fixture an
    ``xdist_group`` (:func:`_shared_fixture_group`), so that under ``--dist loadgroup`` that fixture is built on
    one worker; every other test goes to whichever worker is free."""
    for item in items:
        if DISTILLING_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.slow)
        group = _shared_fixture_group(item)
        if group is not None:
            item.add_marker(pytest.mark.xdist_group(group))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    """Every test marked ``gl`` goes through :func:`require_gl` before any of its fixtures is set up."""
    if item.get_closest_marker("gl") is not None:
        require_gl()


@pytest.fixture(scope="session")
def fox_transforms() -> Path:
    """The real Instant-NGP fox capture's transforms.json (67 frames, 1080x1920, with lens distortion)."""
    return DATA / "fox_transforms.json"


@pytest.fixture(autouse=True)
def fixed_seeds():
    """Every test sees the same random numbers on every run: a failure is reproducible, never a flake."""
    import random

    import numpy as np
    import torch

    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)


@contextlib.contextmanager
def _thread_count_kept():
    """Fails (``pytest.fail``) when torch's thread count at the end of the block differs from its start, after
    putting the start's count back."""
    import torch

    before = torch.get_num_threads()
    yield
    after = torch.get_num_threads()
    if after != before:
        torch.set_num_threads(before)
        pytest.fail(f"the test left torch's thread count at {after} (it was {before}); use the fixtures "
                    "one_torch_thread / two_torch_threads / torch_threads of tests/conftest.py",
                    pytrace=False)


@pytest.fixture(autouse=True)
def torch_thread_count_kept():
    """Fails a test that leaves torch's thread count changed, and puts it back so the tests after it run as
    they would alone. Change it with ``one_torch_thread``, ``two_torch_threads`` or ``torch_threads``, which
    restore it."""
    with _thread_count_kept():
        yield


@contextlib.contextmanager
def _torch_threads(n: int):
    """torch runs on ``n`` threads inside the block; the count it had before is restored after it (also when
    the block raises), so no test leaves its thread count to the tests after it."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(min(n, WORKER_THREADS or n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


@pytest.fixture(scope="session")
def torch_threads():
    """:func:`_torch_threads` for fixtures of any scope: ``with torch_threads(2): ...``."""
    return _torch_threads


@pytest.fixture
def one_torch_thread():
    """Small tensors: one torch thread is faster and immune to a busy shared CPU."""
    with _torch_threads(1):
        yield


@pytest.fixture
def two_torch_threads():
    """End-to-end runs: two torch threads for the test, the previous count restored after it."""
    with _torch_threads(2):
        yield


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    """One small pipeline run (a sphere SDF, fast preset, 128x128 held-out views), shared by the end-to-end and
    the report tests: (DistillResult, run folder). Needs an OpenGL context; the tests using it are marked ``gl``."""
    import neuras_distill as nd
    from neuras_distill.scenes.analytic import SphereSDF

    with _torch_threads(2):
        out = tmp_path_factory.mktemp("e2e") / "run"
        field = SphereSDF(center=(0.0, 0.0, 0.0), radius=0.5)
        cams = field.default_cameras(10, 96, 96)
        cfg = nd.load_config("fast", overrides={"train": {"steps": 250}, "eval": {"width": 128, "fps_frames": 5},
                                                "texture": {"resolution": 128, "num_codes": 128}})
        result = nd.distill(field, cams, cfg, out=out, progress=False, log=lambda m: None)
    return result, out


def pytest_terminal_summary(terminalreporter):
    """One line after the summary when tests of real clients (Chromium, Blender, xvfb, node, OpenGL) were skipped
    because their tool is missing: how many, which tools, and the command that installs them."""
    from real_clients import INSTALL_CLIENTS, missing_tool_skips

    reasons = missing_tool_skips(terminalreporter.stats.get("skipped", []))
    if reasons:
        tools = sorted({r.split(" is ")[0].split(" (")[0] for r in reasons})
        terminalreporter.write_line(f"{len(reasons)} tests of real clients were skipped, their tools missing "
                                    f"({'; '.join(tools)}); to run them: {INSTALL_CLIENTS}", yellow=True)
