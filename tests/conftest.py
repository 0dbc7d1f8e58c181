"""Shared test fixtures: the real data folder, seeded generators, hypothesis profile."""

from __future__ import annotations

import os
import sys

from service.blas import pin_blas_threads

pin_blas_threads()  # as every contourcap process does, before numpy is imported

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pytest

try:
    from hypothesis import settings

    settings.register_profile("ci", derandomize=True, max_examples=50, deadline=None)
    settings.register_profile("dev", max_examples=50, deadline=None)
    # --fuzz-long: the fuzz tests (tests/*/test_fuzz_*.py) run 100x longer (CONTOURCAP_FUZZ_EXAMPLES), not
    # derandomised
    settings.register_profile("fuzz-long", max_examples=int(os.environ.get("CONTOURCAP_FUZZ_EXAMPLES", 5000)),
                              deadline=None)
    settings.load_profile("ci" if os.environ.get("CI") else "dev")
except ImportError:  # pragma: no cover
    pass


def pytest_addoption(parser):
    parser.addoption("--fuzz-long", action="store_true", default=False,
                     help="run the hypothesis property/fuzz tests with 5000 examples each (default 50)")


def pytest_configure(config):
    if config.getoption("--fuzz-long", default=False):
        from hypothesis import settings as _settings

        _settings.load_profile("fuzz-long")

REPO_ROOT = Path(__file__).resolve().parent.parent
if str(REPO_ROOT) not in sys.path:  # tests.support is imported from the repo root however pytest starts
    sys.path.insert(0, str(REPO_ROOT))
SHARED_DATA = REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` relative to the repo root; skips the test where it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
