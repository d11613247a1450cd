"""Where the real data of ../shared/data lives, and a marker for tests that need it."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import shared_data_dir

SHARED_DATA = shared_data_dir()

requires_shared_data = pytest.mark.skipif(
    not (SHARED_DATA / "bandai-ds1").is_dir() or not (SHARED_DATA / "cmu").is_dir(),
    reason=f"real data not found at {SHARED_DATA} (set MOCAP_SHARED_DATA)",
)


def data_folder(name: str) -> Path:
    """``../shared/data/<name>``; the calling test is skipped when that folder is absent (each
    data folder on its own: a machine may have some of them)."""
    path = SHARED_DATA / name
    if not path.is_dir():
        pytest.skip(f"{name}/ not found in {SHARED_DATA} (set MOCAP_SHARED_DATA)")
    return path
