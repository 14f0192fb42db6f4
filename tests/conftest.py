"""Shared test helpers."""

from __future__ import annotations

import os
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


@pytest.fixture
def one_torch_thread():
    """Small tensors: one torch thread is faster and immune to a busy shared CPU."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="session")
def small_run(tmp_path_factory):
    """One small pipeline run (a sphere SDF, fast preset, 128x128 held-out views), shared by the end-to-end and
    the report tests: (DistillResult, run folder). Needs an OpenGL context; the tests using it are marked ``gl``."""
    import torch

    import neuras_distill as nd
    from neuras_distill.scenes.analytic import SphereSDF

    old = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        out = tmp_path_factory.mktemp("e2e") / "run"
        field = SphereSDF(center=(0.0, 0.0, 0.0), radius=0.5)
        cams = field.default_cameras(10, 96, 96)
        cfg = nd.load_config("fast", overrides={"train": {"steps": 250}, "eval": {"width": 128, "fps_frames": 5},
                                                "texture": {"resolution": 128, "num_codes": 128}})
        result = nd.distill(field, cams, cfg, out=out, progress=False, log=lambda m: None)
    finally:
        torch.set_num_threads(old)
    return result, out
