"""The repository on a migrated SQLite file, with synthetic clips and vectors."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.db import browsing as browse_db
from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.db.session import read_sessions, write_sessions


def new_clip(content_hash: str, *, labels: tuple[str, ...] = (), seed: int = 0) -> clip_db.NewClip:
    rng = np.random.default_rng(seed)
    return clip_db.NewClip(
        name=f"clip-{content_hash}",
        format="bvh",
        content_hash=content_hash,
        frame_count=100,
        frame_time=1 / 30,
        duration=100 / 30,
        joint_count=24,
        skeleton_family="test",
        lead_in_frames=0,
        labels=labels,
        files=(clip_db.FileRecord("file", f"{content_hash}.bvh", "ab" * 32, 10),),
        vectors={
            "posture": vector_db.StoredVector(1, rng.normal(size=12).astype(np.float32)),
            "kinetic": vector_db.StoredVector(2, rng.normal(size=5).astype(np.float32)),
        },
    )


@pytest.fixture
def session(engine: Engine) -> Session:
    with write_sessions(engine)() as session:
        return session


def test_insert_get_and_vectors_round_trip(engine: Engine) -> None:
    new = new_clip("h1", labels=("walk", "happy"))
    with write_sessions(engine).begin() as session:
        clip_id = clip_db.insert_clip(session, new)
    with read_sessions(engine)() as session:
        clip = clip_db.get_clip(session, clip_id)
        assert clip is not None
        assert clip.labels == ("walk", "happy")
        assert clip.filenames == ["h1.bvh"]
        assert clip.created_at.tzinfo is not None
        vectors = vector_db.get_vectors(session, clip_id)
        assert set(vectors) == {"posture", "kinetic"}
        np.testing.assert_array_equal(vectors["posture"].vector, new.vectors["posture"].vector)
        assert vectors["kinetic"].version == 2
        ids, array = vector_db.load_vectors(session, "posture", 1, 12)
        assert ids.tolist() == [clip_id] and array.shape == (1, 12)
        assert array.dtype == np.float32 and array.flags.c_contiguous
        # another version or dimension is not loaded into an index of this one
        assert vector_db.load_vectors(session, "posture", 2, 12)[0].size == 0
        assert vector_db.load_vectors(session, "posture", 1, 13)[0].size == 0


def test_ids_no_database_holds_name_no_clip(engine: Engine) -> None:
    """An id past signed 64 bits (or below 1) names no clip: a driver cannot even send it
    (SQLite's: "Python int too large to convert to SQLite INTEGER", a 500 of POST /exports)."""
    with write_sessions(engine).begin() as session:
        clip_id = clip_db.insert_clip(session, new_clip("h1"))
    with read_sessions(engine)() as session:
        for no_id in (2**63, 13161610185593134776320, 0, -18573):
            assert clip_db.get_clip(session, no_id) is None
        assert list(clip_db.get_clips(session, [clip_id, 2**63, -1, 2**80])) == [clip_id]


def test_content_hash_is_unique(engine: Engine) -> None:
    with write_sessions(engine).begin() as session:
        clip_db.insert_clip(session, new_clip("same"))
    with pytest.raises(IntegrityError), write_sessions(engine).begin() as session:
        clip_db.insert_clip(session, new_clip("same"))
    with read_sessions(engine)() as session:
        assert clip_db.count_clips(session) == 1


def test_list_paginates_and_filters_by_label(engine: Engine) -> None:
    with write_sessions(engine).begin() as session:
        ids = [
            clip_db.insert_clip(session, new_clip(f"h{i}", labels=("even",) if i % 2 == 0 else ()))
            for i in range(7)
        ]
    with read_sessions(engine)() as session:
        page, total = clip_db.list_clips(session, label=None, limit=3, offset=3)
        assert total == 7 and [c.id for c in page] == ids[3:6]
        page, total = clip_db.list_clips(session, label="even", limit=10, offset=0)
        assert total == 4 and [c.id for c in page] == ids[0::2]
        assert sorted(label_db.clip_ids_with_label(session, "even").tolist()) == ids[0::2]
        assert clip_db.clip_ids_by_hash(session, ["h1", "nope"]) == {"h1": ids[1]}


def test_update_replaces_labels(engine: Engine) -> None:
    with write_sessions(engine).begin() as session:
        clip_id = clip_db.insert_clip(session, new_clip("h", labels=("a", "b")))
    with write_sessions(engine).begin() as session:
        assert clip_db.update_clip(session, clip_id, name="renamed", labels=["b", "c"])
        assert not clip_db.update_clip(session, clip_id + 1, name="x")
    with read_sessions(engine)() as session:
        clip = clip_db.get_clip(session, clip_id)
        assert clip is not None and clip.name == "renamed" and clip.labels == ("b", "c")


def test_delete_cascades_and_ids_are_not_reused(engine: Engine) -> None:
    with write_sessions(engine).begin() as session:
        first = clip_db.insert_clip(session, new_clip("h1", labels=("x",)))
        second = clip_db.insert_clip(session, new_clip("h2", labels=("x",)))
    with write_sessions(engine).begin() as session:
        assert clip_db.delete_clip(session, second) == ["ab" * 32]
        assert clip_db.delete_clip(session, second) is None
        assert clip_db.referenced_blobs(session, ["ab" * 32, "cd" * 32]) == {"ab" * 32}
    with write_sessions(engine).begin() as session:
        third = clip_db.insert_clip(session, new_clip("h3"))
    assert third > second  # SQLite AUTOINCREMENT: a deleted clip's id never comes back
    with read_sessions(engine)() as session:
        assert vector_db.get_vectors(session, second) == {}
        assert label_db.clip_ids_with_label(session, "x").tolist() == [first]
        assert vector_db.vector_ids(session, "posture", 1, 12).tolist() == [first, third]


def test_clips_needing_vectors_and_put_vectors(engine: Engine) -> None:
    with write_sessions(engine).begin() as session:
        clip_id = clip_db.insert_clip(session, new_clip("h"))
    current = {"posture": 1, "kinetic": 3, "motion": 1}
    with read_sessions(engine)() as session:
        assert vector_db.clips_needing_vectors(session, current) == {clip_id: ["kinetic", "motion"]}
    with write_sessions(engine).begin() as session:
        vector_db.put_vectors(
            session,
            clip_id,
            {
                "kinetic": vector_db.StoredVector(3, np.ones(6, np.float32)),
                "motion": vector_db.StoredVector(1, np.zeros(4, np.float32)),
            },
        )
    with read_sessions(engine)() as session:
        assert vector_db.clips_needing_vectors(session, current) == {}
        assert vector_db.get_vector(session, clip_id, "kinetic") is not None
        stored = vector_db.get_vector(session, clip_id, "kinetic")
        assert stored is not None and stored.vector.shape == (6,)


def test_label_filters_every_read_path(engine: Engine) -> None:
    """All-of and any-case, alike on the Core functions and the browsing query; the bulk
    delete goes by the same rule. (Searches filter in memory: tests/index/test_catalogue.py.)"""
    sets = [("Walk", "happy"), ("walk",), ("HAPPY", "run"), ("walk", "Happy", "x"), ()]
    with write_sessions(engine).begin() as session:
        ids = clip_db.insert_clips(
            session, [new_clip(f"h{i}", labels=s) for i, s in enumerate(sets)]
        )
    want = {
        "walk,happy": [ids[0], ids[3]],
        "HAPPY": [ids[0], ids[2], ids[3]],
        "x,walk,HAPPY": [ids[3]],
        "walk,nothing": [],
    }
    with read_sessions(engine)() as session:
        for label, expected in want.items():
            assert label_db.clip_ids_with_label(session, label).tolist() == expected, label
            assert label_db.clip_ids_with_label(session, label.split(",")).tolist() == expected
            assert label_db.clip_ids_with_labels(session, label) == expected
            found, total = browse_db.find_clip_ids(
                session, name_contains=None, label=label, limit=10, offset=0
            )
            assert (found, total) == (expected, len(expected))
        assert label_db.clip_ids_with_labels(session, "") == ids  # no filter: every clip
    with write_sessions(engine).begin() as session:
        clip_db.delete_clips(session, label_db.clip_ids_with_labels(session, "WALK"))
    with read_sessions(engine)() as session:
        assert label_db.clip_ids_with_labels(session, None) == [ids[2], ids[4]]
