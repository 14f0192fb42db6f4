"""Shared test helpers."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


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
