"""Where the real data of ../shared/data lives, and a marker for tests that need it."""

from __future__ import annotations

import pytest

from tests.conftest import shared_data_dir

SHARED_DATA = shared_data_dir()

requires_shared_data = pytest.mark.skipif(
    not (SHARED_DATA / "bandai-ds1").is_dir() or not (SHARED_DATA / "cmu").is_dir(),
    reason=f"real data not found at {SHARED_DATA} (set MOCAP_SHARED_DATA)",
)
