"""A server's verifier thread (app/services/library_checks.py): what it prepares for the first
searches, and what it rebuilds when a file mapped unchecked at start turns out damaged."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.config import Settings
from app.index.kinds import IVF
from app.index.neighbour_scale import measure
from app.services.ingest import describe, store_many
from app.services.library import open_library
from app.services.search import search_by_clip_id
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion


def stored_library(tmp_path: Path) -> Settings:
    """600 clips whose posture index is an IVF file, saved and mapped."""
    settings = Settings(data_dir=tmp_path / "data", index_type="ivf")
    library = open_library(settings, describer=FakeDescriber())
    uploads = [
        Upload.from_files(file=(f"c{n}.bvh", fake_motion([n % 17, n // 17, 0.5])))
        for n in range(600)
    ]
    store_many(library, [describe(library, u) for u in uploads])
    library.close()
    open_library(settings, describer=FakeDescriber()).close()  # now IVF, saved and mapped
    return settings


def test_the_verifier_prepares_scales_and_forgets_one_measured_on_a_damaged_file(
    tmp_path: Path,
) -> None:
    settings = stored_library(tmp_path)
    library = open_library(settings, describer=FakeDescriber(), verify_later=True)
    try:
        assert library.verifier is not None
        library.verifier.join(timeout=60)
        assert "posture" in library.scales._scales  # ready before any search
        assert (settings.index_dir / "posture.scale.arrays").exists()
        _, vectors = library.indexes["posture"].reconstruct_batch(np.array([300]))
    finally:
        library.close()
    # One stored vector moved far away in the file: only the checksum notices at start.
    index_file = settings.index_dir / "posture.faiss"
    data = index_file.read_bytes()
    stored = vectors[0].astype(np.float32).tobytes()
    assert data.count(stored) == 1
    index_file.write_bytes(data.replace(stored, (vectors[0] * 1e3).astype(np.float32).tobytes()))
    library = open_library(settings, describer=FakeDescriber(), verify_later=True)
    try:
        assert library.verifier is not None
        library.verifier.join(timeout=60)  # measured on the damaged file, then rebuilt it
        index = library.indexes["posture"]
        scale = library.scales.of("posture", index)
        fresh = measure(index, None)
        assert scale.size == fresh.size
        assert scale.distances.tobytes() == fresh.distances.tobytes()
    finally:
        library.close()


def test_server_checks_mapped_files_after_start_and_rebuilds_a_damaged_one(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A server maps its large files unchecked (start-up) and checks them in a thread: a
    damaged one is rebuilt from the database, and searches answer right."""
    settings = stored_library(tmp_path)
    assert json.loads((settings.index_dir / "posture.json").read_text())["kind"] == IVF
    index_file = settings.index_dir / "posture.faiss"
    data = bytearray(index_file.read_bytes())
    data[-5] ^= 0xFF  # a byte of the lists: only the checksum notices
    index_file.write_bytes(bytes(data))
    catalogue_file = settings.index_dir / "catalogue.arrays"
    data = bytearray(catalogue_file.read_bytes())
    data[len(data) // 2] ^= 0xFF
    catalogue_file.write_bytes(bytes(data))
    caplog.set_level("WARNING")
    library = open_library(settings, describer=FakeDescriber(), verify_later=True)
    try:
        assert library.indexes["posture"].mapped
        assert library.verifier is not None  # the check runs in a thread of the library
        library.verifier.join(timeout=60)
        assert library.verify_files() == []  # the thread found and rebuilt both already
        query, hits = search_by_clip_id(library, 1, "posture", 5, label=None)
        assert query.name == "c0" and {h.clip.name for h in hits[:2]} == {"c17", "c1"}
        assert len(library.catalogue) == 600
        assert "rebuilding the posture index" in caplog.text
        assert "rebuilding the catalogue" in caplog.text
    finally:
        library.close()
