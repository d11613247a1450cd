"""A moments query's parts (app/services/moment_parts.py): a clip deleted between its entry
being read and its parts being gathered is not found (404), not a bad request (422)."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.errors import InvalidInput, NotFound
from app.main import create_app
from app.services.clips import delete_clip
from app.services.library import open_library
from app.services.moment_parts import StoredSpan, stored_span_parts
from app.services.synthetic import fill_synthetic
from tests.conftest import FIXTURES_DIR

BANDAI = FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh"


def test_a_clip_deleted_meanwhile_is_not_found(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", index_type="flat")
    with TestClient(create_app(settings)) as client:
        response = client.post("/clips", files={"file": (BANDAI.name, BANDAI.read_bytes())})
        assert response.status_code == 201, response.text
    fill_synthetic(settings, 3, report=lambda _message: None)  # clips without a file
    library = open_library(settings)
    try:
        synthetic = [e for e in map(library.clip_entry, range(1, 5)) if e and not e.filenames]
        kept, deleted = synthetic[:2]
        version = library.descriptor("motion").version
        # a part of a clip without a file and not a stored window: nothing to describe it from
        with pytest.raises(InvalidInput):
            stored_span_parts(library, StoredSpan(kept, "motion", version, 1, 2))
        delete_clip(library, deleted.id)
        # its entry read before the delete: what a search racing the delete holds
        for first, stop in ((1, 2), (deleted.lead_in_frames, deleted.frame_count)):
            with pytest.raises(NotFound):
                stored_span_parts(library, StoredSpan(deleted, "motion", version, first, stop))
    finally:
        library.close()
