"""Shared test helpers."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def fox_transforms() -> Path:
    """The real Instant-NGP fox capture's transforms.json (67 frames, 1080x1920, with lens distortion)."""
    return DATA / "fox_transforms.json"
