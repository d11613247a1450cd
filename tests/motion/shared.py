"""Where the real data of ../shared/data lives, and a marker for tests that need it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
SHARED_DATA = Path(os.environ.get("MOCAP_SHARED_DATA", REPO_ROOT.parent / "shared" / "data"))

requires_shared_data = pytest.mark.skipif(
    not (SHARED_DATA / "bandai-ds1").is_dir() or not (SHARED_DATA / "cmu").is_dir(),
    reason=f"real data not found at {SHARED_DATA} (set MOCAP_SHARED_DATA)",
)
