"""Shared fixtures: where ../shared/scenes lives, and skips when it is absent."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_SCENES = REPO.parent / "shared" / "scenes"


KERNELS = "BCFPIPE_TEST_KERNELS"  # the session's compiled kernels, shared by its xdist workers


def pytest_configure(config) -> None:
    """One compiled-kernel cache for the whole session (issue 59): numba's and the fused C++
    kernel's (`bcfpipe.process_env.kernels_dir`: NUMBA_CACHE_DIR wins over a build's
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


# Longest work unit first (LPT): a module's summed test time, or for a `PER_TEST` module its longest
# test, in `make test` at 523a6ca. xdist hands units out in collection order, so the long ones start
# first and the short ones fill the gaps at the end rather than one long unit trailing alone.
LONGEST_FIRST = ("test_wrap", "test_render", "test_fused", "test_bench", "test_many_layers", "test_native_fallback",
                 "test_classic_layout", "test_build", "test_classic_estimate", "test_extremes", "test_vulkan",
                 "test_glsl", "test_fuzz", "test_blocks_cache", "test_verify", "test_fold", "test_incremental",
                 "test_rate", "test_faults", "test_predict", "test_concurrency", "test_parallel_encode",
                 "test_usd_classic", "test_reports", "test_bc7", "test_t0_width", "test_fixed_t0", "test_layout",
                 "test_shard", "test_jobs_bound")
# Long modules whose tests share nothing: under `make test`'s --dist loadscope each of their tests
# goes to whichever worker is free, not the whole module to one (tests/conftest.py checks that none
# uses a module- or class-scoped fixture, which would then be made on both workers).
PER_TEST = ("test_extremes", "test_incremental", "test_fused", "test_rate", "test_fold", "test_concurrency",
            "test_faults", "test_predict", "test_fixed_t0", "test_native_fallback", "test_blocks_cache",
            "test_bad_images")
SHARED_SCOPES = ("module", "class", "package")


def pytest_collection_modifyitems(config, items) -> None:
    """The longest modules first (`LONGEST_FIRST`); a `PER_TEST` module that uses a shared fixture
    is a mistake here, said before anything runs."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.stem, len(rank)))
    for item in items:
        defs = getattr(item, "_fixtureinfo", None)
        if item.path.stem in PER_TEST and defs is not None and any(
                d.scope in SHARED_SCOPES for ds in defs.name2fixturedefs.values() for d in ds):
            raise pytest.UsageError(f"{item.nodeid} uses a {SHARED_SCOPES} fixture: take {item.path.stem} out of "
                                    "tests/conftest.py PER_TEST")


@pytest.hookimpl(optionalhook=True)  # xdist's hook: `-p no:xdist` runs have no such hook
def pytest_xdist_make_scheduler(config, log):
    """--dist loadscope (`make test`), with each test of a `PER_TEST` module a unit of its own."""
    if config.getvalue("dist") != "loadscope":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Scheduler(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if Path(nodeid.split("::", 1)[0]).stem in PER_TEST:
                return nodeid
            return super()._split_scope(nodeid)

    return Scheduler(config, log)


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
