"""Search by a stored clip while another request deletes it (real database, files and
indexes; the fake motion core of tests/services/fakes.py chooses the vectors)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from app.config import Settings
from app.db import clips as clip_db
from app.errors import NotFound
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.search import find_by_clip
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion


@pytest.fixture
def library(settings: Settings) -> Iterator[Library]:
    library = open_library(settings, describer=FakeDescriber())
    yield library
    library.close()


def test_a_clip_deleted_half_way_through_a_search_is_not_found(library: Library) -> None:
    """A delete commits the row, then drops the vectors from the indexes, then from the
    catalogue. A search that found the clip in the catalogue and then missed it in the index
    was answered 409 'no vector of version 1 yet; run reindex' (a crowd test met it): the
    clip is gone, 404."""
    first = ingest(library, Upload.from_files(file=("a.bvh", fake_motion([1, 2, 3])))).clip
    ingest(library, Upload.from_files(file=("b.bvh", fake_motion([1, 2, 4]))))
    assert find_by_clip(library, first.id, "posture", 1).hits
    # The delete's first two steps, as clips.delete_clip takes them; the catalogue is next.
    with library.writes.begin() as session:
        clip_db.delete_clip(session, first.id)
    library.indexes["posture"].remove([first.id])
    assert library.clip_entry(first.id) is not None  # still in the catalogue
    with pytest.raises(NotFound, match=f"no clip with id {first.id}"):
        find_by_clip(library, first.id, "posture", 1)
    library.catalogue.apply_changes(np.asarray([first.id], np.int64), {})
    with pytest.raises(NotFound):
        find_by_clip(library, first.id, "posture", 1)
