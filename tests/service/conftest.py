"""Fixtures of the service tests: a studio of worker threads on loopback zenoh."""

from __future__ import annotations

import pytest

from service.wire.bus import Keys
from tests.support.workers import Studio


@pytest.fixture
def studio():
    """Track, segment and camera workers as threads on a fresh loopback port; closed after the test."""
    st = Studio(Keys("wk"))
    yield st
    st.close()
