"""Reading a stored clip's files while another request deletes the clip."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from app.config import Settings
from app.errors import NotFound, StorageUnavailable
from app.services.clips import clip_download, delete_clip, get_clip, stored_bytes
from app.services.export import Exporter, ExportItem, ExportOptions, export_each
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.uploads import Upload
from tests.hardening.live import unique_upload


@pytest.fixture
def library(tmp_path: Path) -> Iterator[Library]:
    opened = open_library(Settings(data_dir=tmp_path / "data"))
    try:
        yield opened
    finally:
        opened.close()


def stored(library: Library, n: int) -> int:
    fields = unique_upload(3 * n + 2)  # an ASF skeleton with an AMC motion: two files
    upload = Upload.from_files(skeleton=fields["skeleton"], motion=fields["motion"])
    return ingest(library, upload).clip.id


def test_a_clip_deleted_while_it_is_read_is_not_found(library: Library) -> None:
    """A download or export that read the clip's record before a delete and its files after
    answered 503 ``storage_unavailable`` ("stored file ... cannot be read: No such file or
    directory", found racing ``POST /exports`` with ``DELETE /clips/{id}``): the data
    directory is fine, the clip is gone, so 404 saying so."""
    kept, deleted = stored(library, 0), stored(library, 1)
    record = get_clip(library, deleted)
    delete_clip(library, deleted)  # its AMC goes (the ASF stays: the other clip uses it)
    for read in (
        lambda: clip_download(library, record, None),  # the ZIP of both files
        lambda: clip_download(library, record, "motion"),
        lambda: clip_download(library, record, None, start=0.0, end=0.1),  # cut
        lambda: clip_download(library, record, None, as_bvh=True),
    ):
        with pytest.raises(NotFound, match=f"clip {deleted} was deleted while it was being read"):
            read()
    exporter = Exporter(library, ExportOptions(format="bvh"))
    items = [ExportItem(get_clip(library, kept), None, None), ExportItem(record, None, None)]
    (_, first, no_error), (_, second, error) = export_each(exporter, items)
    assert first is not None and no_error == ""
    assert second is None and error.startswith("not_found: clip"), error
    # A file missing under a clip that is still stored is the data directory's fault: 503.
    motion = next(f for f in get_clip(library, kept).files if f.role == "motion")
    library.blobs.path(motion.sha256).unlink()  # type: ignore[attr-defined]
    with pytest.raises(StorageUnavailable):
        stored_bytes(library, get_clip(library, kept), motion.sha256)
