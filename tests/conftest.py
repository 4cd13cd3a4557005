"""Shared fixtures: where ../shared/scenes lives, and skips when it is absent."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_SCENES = REPO.parent / "shared" / "scenes"


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    if not SHARED_SCENES.is_dir():
        pytest.skip(f"needs the shared scenes at {SHARED_SCENES} (not present)")
    return SHARED_SCENES
