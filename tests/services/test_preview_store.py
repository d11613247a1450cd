"""A deleted clip's stored preview goes with it: its motion does not stay on disk. Real
files, a real SQLite library."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from app.config import Settings
from app.services import previews
from app.services.clips import delete_clip, delete_clips_with
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.preview_store import preview_store
from app.services.uploads import Upload
from tests.conftest import FIXTURES_DIR

CLIPS = ("cmu_mb_02_01_first41.bvh", "bandai_walk_normal_001_first40.bvh")


@pytest.fixture
def library(settings: Settings) -> Iterator[Library]:
    library = open_library(settings)
    yield library
    library.close()


def test_deleting_clips_removes_their_stored_previews(library: Library) -> None:
    store = preview_store(library.settings)
    version = previews.preview_version(library)
    clips = []
    for name, label in zip(CLIPS, ("kept", "gone"), strict=True):
        upload = Upload.from_files(file=(name, (FIXTURES_DIR / name).read_bytes()), labels=[label])
        clips.append(ingest(library, upload).clip)
    by_hand = ingest(
        library, Upload.from_files(file=("tiny.bvh", (FIXTURES_DIR / CLIPS[0]).read_bytes()[:-2]))
    ).clip
    paths = [store.path(c.content_hash, version) for c in (*clips, by_hand)]
    assert all(p.is_file() for p in paths)
    # An older preview version of the same content goes too.
    older = store.path(by_hand.content_hash, "0" * len(version))
    older.write_bytes(paths[2].read_bytes())

    delete_clip(library, by_hand.id)
    assert not paths[2].exists() and not older.exists()
    assert delete_clips_with(library, "gone") == 1
    assert not paths[1].exists()
    assert paths[0].is_file()  # the clip still stored keeps its preview
