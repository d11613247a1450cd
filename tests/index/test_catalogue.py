"""The in-memory catalogue (app/index/catalogue.py): its reads against a plain model, its file,
and — on real SQLite and PostgreSQL databases — that it agrees with the database after
uploads, deletes, relabels, renames, another replica's changes and a restart after kill -9,
so every search's hits carry exactly the database's data."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from app.config import Settings
from app.db.clip_filters import ClipFilter, selected_ids
from app.db.clips import AnimationRecord
from app.db.entries import ClipEntry, clip_entries
from app.index import catalogue as catalogue_module
from app.index.catalogue import Catalogue
from app.labels import label_key
from app.licences import licence_filter
from app.services import clips as clip_service
from app.services.ingest import ingest
from app.services.library import Library, open_library
from app.services.search import search_by_clip_id
from app.services.uploads import Upload
from tests.services.fakes import FakeDescriber, fake_motion

LABELS = ["walk", "Walk", "RUN", "happy", "sad", "jump"]
LICENCES = [None, "CC BY 4.0", "CC0", "studio only"]


def entry(clip_id: int, **changes: object) -> ClipEntry:
    base = ClipEntry(
        id=clip_id,
        name=f"clip {clip_id}",
        format="bvh",
        filenames=(f"c{clip_id}.bvh",),
        skeleton_family="bandai",
        labels=(),
        frame_count=30 + clip_id,
        frame_time=1 / 30,
        duration=(30 + clip_id) / 30,
        source=None,
        licence=None,
        content_hash=f"{clip_id:064x}",
        joint_count=20,
        lead_in_frames=0,
        warnings=(),
        animations=None,
        created_at=datetime(2024, 1, 2, 3, 4, 5, clip_id, tzinfo=UTC),
    )
    return base._replace(**changes)  # type: ignore[arg-type]


entries_strategy = st.builds(
    lambda clip_id, name, labels, licence, source, animated: entry(
        clip_id,
        name=name,
        labels=tuple(dict.fromkeys(labels)),
        licence=licence,
        source=source,
        animations=(AnimationRecord("take", 10, 0.5, True),) if animated else None,
        warnings=("odd",) if animated else (),
    ),
    st.integers(1, 60),
    st.text(min_size=1, max_size=8),
    st.lists(st.sampled_from(LABELS), max_size=3),
    st.sampled_from(LICENCES),
    st.sampled_from([None, "mocap lab", "é"]),
    st.booleans(),
)


def model_ids_with(model: dict[int, ClipEntry], labels: list[str]) -> list[int]:
    keys = {label_key(label) for label in labels}
    return sorted(i for i, e in model.items() if keys <= e.label_keys())


def check_against(catalogue: Catalogue, model: dict[int, ClipEntry]) -> None:
    assert len(catalogue) == len(model)
    assert catalogue.ids().tolist() == sorted(model)
    assert list(catalogue.entries()) == [model[i] for i in sorted(model)]
    for clip_id in range(0, 62):
        assert catalogue.get(clip_id) == model.get(clip_id)
    assert catalogue.get_many(range(62)) == model
    assert catalogue.frames(range(62)) == {
        i: (e.frame_time, e.frame_count) for i, e in model.items()
    }
    asked = np.array([61, *range(62), 3], np.int64)  # any order, repeats, absent ids
    held, facts = catalogue.frame_arrays(asked)
    assert held.tolist() == [int(i) in model for i in asked]
    assert facts.dtype == np.float64
    assert facts.tolist() == [
        [model[i].frame_time, model[i].frame_count] for i in asked.tolist() if i in model
    ]
    for labels in (["walk"], ["WALK", "happy"], ["run"], ["nobody"], ["sad", "jump", "walk"]):
        assert catalogue.ids_with_labels(labels).tolist() == model_ids_with(model, labels)
    assert catalogue.ids_with_labels(None).tolist() == sorted(model)
    for licence in LICENCES:
        found = catalogue.ids_matching("licence", lambda value, want=licence: value == want)
        assert found.tolist() == sorted(i for i, e in model.items() if e.licence == licence)


operations = st.lists(
    st.one_of(
        st.tuples(st.just("put"), st.lists(entries_strategy, max_size=6)),
        st.tuples(st.just("delete"), st.lists(st.integers(1, 60), max_size=6)),
        st.tuples(st.sampled_from(["save", "compact", "reload"]), st.none()),
    ),
    max_size=12,
)


@hypothesis_settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(first=st.lists(entries_strategy, max_size=20), steps=operations)
def test_catalogue_reads_agree_with_a_plain_model(
    tmp_path_factory: pytest.TempPathFactory,
    first: list[ClipEntry],
    steps: list[tuple[str, object]],
) -> None:
    directory = tmp_path_factory.mktemp("catalogue")
    model = {e.id: e for e in first}
    catalogue = Catalogue(directory, autosave_below=0)
    catalogue.replace_all(model.values(), synced_to=1)
    check_against(catalogue, model)
    for kind, argument in steps:
        if kind == "put":
            changed = {e.id: e for e in argument}  # type: ignore[attr-defined]
            catalogue.apply_changes(np.array(list(changed), np.int64), changed)
            model.update(changed)
        elif kind == "delete":
            gone = np.array(argument, np.int64)
            catalogue.apply_changes(gone, {})
            for clip_id in gone.tolist():
                model.pop(clip_id, None)
        elif kind == "save":
            catalogue.save()
        elif kind == "compact":
            catalogue.compact()
        else:  # a new process: the saved file, then the changes since (none here)
            catalogue.save()
            catalogue = Catalogue(directory, autosave_below=0)
            found = catalogue.read_file()
            assert not isinstance(found, str), found
            catalogue.load_or_rebuild(_ModelSource(model, catalogue.synced_to), found)
        check_against(catalogue, model)


class _ModelSource:
    """The database as a dict, for load_or_rebuild."""

    def __init__(
        self, model: dict[int, ClipEntry], position: int, changed: tuple[int, ...] = ()
    ) -> None:
        self._model, self._position, self._changed = model, position, list(changed)

    def watermark(self) -> int:
        return self._position

    def count(self) -> int:
        return len(self._model)

    def ids(self) -> np.ndarray:
        return np.array(sorted(self._model), np.int64)

    def entries(self) -> Iterator[ClipEntry]:
        return iter([self._model[i] for i in sorted(self._model)])

    def changed(self, since: int) -> np.ndarray:
        return np.array(self._changed, np.int64)

    def entries_of(self, ids: np.ndarray) -> dict[int, ClipEntry]:
        return {i: self._model[i] for i in ids.tolist() if i in self._model}


def test_file_behind_catches_up_and_damaged_file_is_rebuilt(tmp_path: Path) -> None:
    model = {i: entry(i, labels=("walk",)) for i in range(1, 6)}
    first = Catalogue(tmp_path)
    first.replace_all(model.values(), synced_to=3)
    # Later (feed position 7): clip 2 renamed, clip 3 deleted, clip 9 added.
    model[2] = entry(2, name="renamed", labels=("run",))
    del model[3]
    model[9] = entry(9, labels=("walk",))
    later = Catalogue(tmp_path)
    assert later.load_or_rebuild(_ModelSource(model, 7, changed=(2, 3, 9))) is None
    check_against(later, model)
    assert later.synced_to == 7
    # The catch-up was saved: a third process starts from position 7.
    again = Catalogue(tmp_path)
    assert again.load_or_rebuild(_ModelSource(model, 7)) is None
    check_against(again, model)
    # A flipped byte in the file: only the checksum notices; rebuilt from the database.
    path = tmp_path / "catalogue.arrays"
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    damaged = Catalogue(tmp_path)
    reason = damaged.load_or_rebuild(_ModelSource(model, 7))
    assert reason is not None and "checksum" in reason
    check_against(damaged, model)
    # Missing a clip the feed did not name (a file from another database): the count says.
    model[11] = entry(11)
    stale = Catalogue(tmp_path)
    reason = stale.load_or_rebuild(_ModelSource(model, 8))
    assert reason is not None and "clips" in reason
    check_against(stale, model)


def test_saved_file_is_shared_memory_not_a_copy(tmp_path: Path) -> None:
    catalogue = Catalogue(tmp_path)
    catalogue.replace_all([entry(i) for i in range(1, 100)], synced_to=1)
    blob = catalogue._state.base.blob
    assert isinstance(blob.base, memoryview) or not blob.flags.owndata  # a view of the map
    assert not blob.flags.writeable


def test_overlay_compacts_past_its_share(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(catalogue_module, "COMPACT_MIN", 3)
    catalogue = Catalogue(tmp_path, autosave_below=0)
    catalogue.replace_all([entry(i) for i in range(1, 10)], synced_to=1)
    catalogue.apply_changes(np.array([1, 2]), {1: entry(1, name="one")})
    assert len(catalogue._state.overlay) == 2
    catalogue.apply_changes(np.array([20, 21]), {20: entry(20), 21: entry(21)})
    assert not catalogue._state.overlay  # merged into a new base, saved
    model = {i: entry(i) for i in range(1, 10) if i != 2} | {1: entry(1, name="one")}
    check_against(catalogue, model | {20: entry(20), 21: entry(21)})


# -- against the database -------------------------------------------------------------------


def database_entries(library: Library) -> dict[int, ClipEntry]:
    with library.reads() as session:
        return {e.id: e for e in clip_entries(session)}


def assert_agrees(library: Library) -> None:
    """The catalogue holds exactly the database's clips, and every search shows them as the
    database has them."""
    stored = database_entries(library)
    assert {e.id: e for e in library.catalogue.entries()} == stored
    for clip_id in sorted(stored)[:6]:
        query, hits = search_by_clip_id(library, clip_id, "posture", 50, label=None)
        assert query == stored[clip_id]
        assert {h.clip.id for h in hits} == set(stored) - {clip_id}
        for hit in hits:
            assert hit.clip == stored[hit.clip.id]
    for label in ("walk", "RUN,happy"):
        keys = {label_key(part) for part in label.split(",")}
        want = sorted(i for i, e in stored.items() if keys <= e.label_keys())
        assert library.catalogue.ids_with_labels(label).tolist() == want
    for licence in ("cc by 4.0", "!CC0", "CC0,studio only", "!cc by 4.0,!studio only"):
        wanted = licence_filter(licence)
        with library.reads() as session:
            want = selected_ids(session, ClipFilter.of(licence=licence))
        assert library.catalogue.ids_matching("licence", wanted.allows).tolist() == want


def upload(n: int, labels: list[str], **fields: str | None) -> Upload:
    return Upload.from_files(
        file=(f"take_{n}.bvh", fake_motion([float(n), float(n % 3), 0.5])),
        labels=labels,
        **fields,  # type: ignore[arg-type]
    )


# Names every database stores (PostgreSQL's text holds no NUL, neither database a lone
# surrogate, which has no UTF-8; the API refuses both, tests/api/test_bad_input.py, and what
# a rename with one answers is not this test's subject).
NAMES = st.text(
    st.characters(blacklist_characters="\x00", blacklist_categories=("Cs",)),
    min_size=1,
    max_size=12,
)

library_operations = st.lists(
    st.one_of(
        st.tuples(st.just("upload"), st.integers(0, 30), st.lists(st.sampled_from(LABELS))),
        st.tuples(st.just("again"), st.integers(0, 30), st.lists(st.sampled_from(LABELS))),
        st.tuples(st.just("delete"), st.integers(0, 100), st.none()),
        st.tuples(st.just("relabel"), st.integers(0, 100), st.lists(st.sampled_from(LABELS))),
        st.tuples(st.just("rename"), st.integers(0, 100), NAMES),
        st.tuples(st.just("licence"), st.integers(0, 100), st.sampled_from(LICENCES)),
        st.tuples(st.just("bulk"), st.integers(0, 100), st.lists(st.sampled_from(LABELS))),
        st.tuples(st.just("bulk delete"), st.integers(0, 100), st.none()),
    ),
    min_size=1,
    max_size=14,
)


def apply(library: Library, kind: str, n: int, argument: object) -> None:
    stored = sorted(library.catalogue.ids().tolist())
    if kind == "upload":
        ingest(library, upload(n, argument))  # type: ignore[arg-type]
    elif kind == "again":  # the same content again: labels added, a name given
        ingest(library, upload(n, argument, name=f"again {n}"))  # type: ignore[arg-type]
    elif not stored:
        return
    elif kind == "delete":
        clip_service.delete_clip(library, stored[n % len(stored)])
    elif kind == "relabel":
        labels = tuple({label_key(x): x for x in argument}.values())  # type: ignore[attr-defined]
        clip_service.update_clip(library, stored[n % len(stored)], name=None, labels=labels)
    elif kind == "rename":
        clip_service.update_clip(library, stored[n % len(stored)], name=str(argument), labels=None)
    elif kind == "licence":
        clip_service.update_clip(
            library, stored[n % len(stored)], name=None, labels=None, notes={"licence": argument}
        )
    elif kind == "bulk":  # POST /clips/labels: the clips of a licence, one label on, one off
        labels: list[str] = argument  # type: ignore[assignment]
        chosen = ClipFilter.of(licence=LICENCES[1 + n % (len(LICENCES) - 1)])
        clip_service.relabel_clips(
            library, chosen, add=tuple(labels[:1]) or ("new",), remove=tuple(labels[1:2])
        )
    else:  # DELETE /clips?label=...
        clip_service.delete_clips_with(library, ClipFilter.of(label=[LABELS[n % len(LABELS)]]))


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
@hypothesis_settings(
    max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(steps=library_operations)
def test_catalogue_agrees_with_the_database_after_random_operations(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    backend: str,
    steps: list[tuple[str, int, object]],
) -> None:
    """Random uploads, repeated uploads, deletes, relabels, renames, licence changes, bulk
    relabels (by licence) and bulk deletes (by label) through the services: after each,
    this process's catalogue and searches show exactly the database's data (at once: the
    writes apply their own changes); a second replica on the same database agrees after
    following the feed; so does a library opened anew."""
    url = request.getfixturevalue("postgres_url") if backend == "postgresql" else None
    data = tmp_path_factory.mktemp("data")
    settings = Settings(data_dir=data, database_url=url, index_refresh_seconds=0)
    library = open_library(settings, describer=FakeDescriber())
    # A replica: its own index directory, the same database.
    replica_settings = settings.model_copy(update={"data_dir": data / "replica"})
    replica = open_library(replica_settings, describer=FakeDescriber()) if url else None
    try:
        for kind, n, argument in steps:
            apply(library, kind, n, argument)
            assert_agrees(library)
        if replica is not None:
            replica.sync_indexes()
            assert_agrees(replica)
    finally:
        library.close()
        if replica is not None:
            replica.close()
    reopened = open_library(settings, describer=FakeDescriber())
    try:
        assert_agrees(reopened)
    finally:
        reopened.close()


KILLED_WRITER = textwrap.dedent(
    """
    import os, signal, sys
    from app.config import Settings
    from app.services import clips as clip_service
    from app.services.ingest import ingest
    from app.services.library import open_library
    from tests.index.test_catalogue import upload
    from tests.services.fakes import FakeDescriber

    library = open_library(Settings(data_dir=sys.argv[1]), describer=FakeDescriber())
    ids = [ingest(library, upload(n, ["walk"])).clip.id for n in range(4)]
    library.catalogue.flush()  # the file holds these four
    library.catalogue.autosave = False  # from here on the file falls behind the database
    for n in range(4, 7):
        ingest(library, upload(n, ["walk"]))
    clip_service.update_clip(library, ids[0], name="renamed", labels=("run", "happy"))
    clip_service.delete_clip(library, ids[1])
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_catalogue_after_kill_9_agrees_with_the_database(tmp_path: Path) -> None:
    """A process killed (SIGKILL) after its catalogue file fell behind the database: the next
    one loads the file, applies the feed since it, and agrees with the database."""
    data = tmp_path / "data"
    root = Path(__file__).resolve().parents[2]
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env["PYTHONPATH"] = str(root)
    done = subprocess.run(
        [sys.executable, "-c", KILLED_WRITER, str(data)],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == -signal.SIGKILL, done.stderr
    assert (data / "indexes" / "catalogue.arrays").exists()
    library = open_library(Settings(data_dir=data), describer=FakeDescriber())
    try:
        assert len(library.catalogue) == 6
        assert_agrees(library)
    finally:
        library.close()
