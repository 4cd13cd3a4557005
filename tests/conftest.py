"""Shared fixtures: where ../shared/scenes lives, and skips when it is absent."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_SCENES = REPO.parent / "shared" / "scenes"


KERNELS = "BCFPIPE_TEST_KERNELS"  # the session's compiled kernels, shared by its xdist workers


def pytest_configure(config) -> None:
    """One compiled-kernel cache for the whole session (issue 59): numba's and the fused C++
    kernel's (`bcfpipe.train.fused.common.kernels_dir`: NUMBA_CACHE_DIR wins over a build's
    --cache), made once by the controller before its xdist workers start and inherited by every
    CLI subprocess; without it each build into a fresh --cache compiled them again. Removed at
    the end of the session."""
    import os
    import tempfile

    if KERNELS not in os.environ and not hasattr(config, "workerinput"):
        os.environ[KERNELS] = tempfile.mkdtemp(prefix="bcfpipe-test-kernels-")
        config._bcfpipe_kernels = os.environ[KERNELS]
    os.environ["NUMBA_CACHE_DIR"] = os.environ.get(KERNELS, os.environ.get("NUMBA_CACHE_DIR", ""))


def pytest_unconfigure(config) -> None:
    import os
    import shutil

    made = getattr(config, "_bcfpipe_kernels", None)
    if made:
        shutil.rmtree(made, ignore_errors=True)
        os.environ.pop(KERNELS, None)


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    if not SHARED_SCENES.is_dir():
        pytest.skip(f"needs the shared scenes at {SHARED_SCENES} (not present)")
    return SHARED_SCENES


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    """Builds in the tests use a cache of their own (one per xdist worker), never the user's."""
    import os

    root = tmp_path_factory.mktemp("bcfpipe-cache")
    old = os.environ.get("BCFPIPE_CACHE")
    os.environ["BCFPIPE_CACHE"] = str(root)
    yield root
    if old is None:
        os.environ.pop("BCFPIPE_CACHE", None)
    else:
        os.environ["BCFPIPE_CACHE"] = old


@pytest.fixture(scope="module")
def rt():
    """A headless OpenGL 4.5 runtime (bcfpipe.verify.glsl) per test module; skips without EGL."""
    from bcfpipe.verify import glsl

    try:
        r = glsl.GLRuntime()
    except glsl.GLUnavailable as e:
        pytest.skip(str(e))
    yield r
    r.release()
