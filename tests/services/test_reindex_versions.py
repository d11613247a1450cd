"""A library stored under the previous versions of ``kinetic`` (2) and ``motion`` (3), before
the hand was read at the palm (issue 22), gets the new vectors from ``reindex``.

At start the service counts the outdated vectors and warns; searches under ``kinetic`` and
``motion`` answer 409 ``descriptor_outdated`` until ``mocap-index reindex`` recomputes them
from the stored files, clip vectors and moments' windows alike; ``posture``, whose version
did not change, keeps working throughout. Real clips (a CMU BVH whose hands have fingers, a
Bandai walk), the real describer and SQLite."""

from __future__ import annotations

import logging
import sqlite3

import numpy as np
import pytest

from app.config import Settings
from app.errors import DescriptorOutdated
from app.motion.descriptors import REGISTRY
from app.services import clips as clip_service
from app.services.ingest import ingest
from app.services.library import open_library
from app.services.reindex import reindex
from app.services.search import search_by_clip
from app.services.uploads import Upload
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes

CHANGED = ("kinetic", "motion")


def _previous_release(settings: Settings) -> None:
    """Make the stored ``kinetic`` and ``motion`` rows (clip vectors and windows) what the
    previous release wrote: one version back, and other numbers (zeros: a reindex that kept
    them would show)."""
    with sqlite3.connect(settings.data_dir / "mocap-index.sqlite3") as db:
        for table in ("clip_descriptors", "clip_windows"):
            db.execute(
                f"UPDATE {table} SET version = version - 1, vector = zeroblob(length(vector)) "
                "WHERE name IN (?, ?)",
                CHANGED,
            )


def test_a_library_of_the_previous_kinetic_and_motion_gets_the_new_vectors_by_reindex(
    settings: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    assert REGISTRY["kinetic"].version == 3 and REGISTRY["motion"].version == 5
    library = open_library(settings)
    try:
        fingers = ingest(
            library, Upload.from_files(file=("cmu.bvh", fixture_bytes(CMU_BVH_FIXTURE)))
        ).clip
        walk = ingest(
            library, Upload.from_files(file=("walk.bvh", fixture_bytes(BANDAI_FIXTURE)))
        ).clip
        fresh = {c.id: clip_service.clip_vectors(library, c.id) for c in (fingers, walk)}
    finally:
        library.close()

    _previous_release(settings)
    with caplog.at_level(logging.WARNING):
        library = open_library(settings)
    try:
        # The start names each outdated descriptor and the command that recomputes it.
        for name in CHANGED:
            assert f"2 clips have {name!r} vectors of an older version" in caplog.text
        assert "'posture' vectors" not in caplog.text
        for name in CHANGED:
            with pytest.raises(DescriptorOutdated, match="mocap-index reindex"):
                search_by_clip(library, fingers, name, 5, label=None)
        assert [h.clip.id for h in search_by_clip(library, fingers, "posture", 5, label=None)]
        report = reindex(library)
        assert report.recomputed == 2 and not report.failed
        for clip in (fingers, walk):
            stored = clip_service.clip_vectors(library, clip.id)
            for name, descriptor in REGISTRY.items():
                assert stored[name].version == descriptor.version
                np.testing.assert_array_equal(stored[name].vector, fresh[clip.id][name].vector)
        hits = search_by_clip(library, fingers, "motion", 5, label=None)
        assert [h.clip.id for h in hits] == [walk.id]
    finally:
        library.close()
    with sqlite3.connect(settings.data_dir / "mocap-index.sqlite3") as db:
        windows = set(db.execute("SELECT DISTINCT name, version FROM clip_windows"))
    # Moments' windows too are recomputed under the new versions, none left behind.
    assert windows and all(version == REGISTRY[name].version for name, version in windows)
