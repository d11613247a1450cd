"""``mocap-index import``: real files in, clips out — pairing, duplicates, failures, labels."""

from __future__ import annotations

import os
import shutil
import signal
import sqlite3
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from app.cli import main
from app.config import Settings
from app.db import clips as clip_db
from app.importer import LabelRules, WorkerPool, run_import
from app.services.library import open_library
from app.services.search import search_by_clip_id
from tests.conftest import SharedData

BVH_FIXTURES = ("bandai_walk_normal_001_first40.bvh", "cmu_mb_02_01_first41.bvh")


@pytest.fixture
def folder(tmp_path: Path, fixtures_dir: Path) -> Path:
    """``clips/``: two BVH files, and an ASF/AMC pair one folder down."""
    root = tmp_path / "clips"
    (root / "cmu" / "02").mkdir(parents=True)
    for name in BVH_FIXTURES:
        shutil.copy(fixtures_dir / name, root / name)
    shutil.copy(fixtures_dir / "cmu_02.asf", root / "cmu" / "02" / "cmu_02.asf")
    shutil.copy(fixtures_dir / "cmu_02_01_first40.amc", root / "cmu" / "02" / "02_01.amc")
    return root


def rows(settings: Settings, sql: str) -> list[tuple]:
    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    try:
        return db.execute(sql).fetchall()
    finally:
        db.close()


def test_import_pairs_skeletons_stores_everything_and_is_idempotent(
    folder: Path, settings: Settings, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import", "--data-dir", str(settings.data_dir), "--no-progress", str(folder)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "imported 3, skipped 0 as duplicates, failed 0 of 3 clips found" in out
    asf = folder / "cmu" / "02" / "cmu_02.asf"
    assert f"skeleton {asf} used for 1 .amc clip" in out
    stored = rows(settings, "SELECT name, format FROM clips ORDER BY name")
    assert stored == [
        ("02_01", "asf/amc"),
        ("bandai_walk_normal_001_first40", "bvh"),
        ("cmu_mb_02_01_first41", "bvh"),
    ]
    assert rows(settings, "SELECT count(*) FROM clip_files") == [(4,)]  # asf + amc + 2 bvh
    windows = rows(settings, "SELECT count(*) FROM clip_windows")[0][0]
    library = open_library(settings)
    try:
        # Every index was saved when the run ended (none during it): loaded as saved.
        assert all(index.unsaved_changes == 0 for index in library.window_indexes.values())
        assert sum(library.window_indexes.sizes().values()) == windows > 0
        assert set(library.indexes.sizes().values()) == {3}
        assert library.clip_count() == 3
        query, hits = search_by_clip_id(library, 1, "posture", 5, label=None)
        assert len(hits) == 2 and query.id not in [h.clip.id for h in hits]
    finally:
        library.close()

    # Again: everything is a duplicate, nothing is stored twice, exit code 0.
    assert main([*argv, "--verbose"]) == 0
    out = capsys.readouterr().out
    assert "imported 0, skipped 3 as duplicates, failed 0" in out
    assert "duplicate " in out and "same content as clip" in out
    assert rows(settings, "SELECT count(*) FROM clips") == [(3,)]


def test_bad_and_orphan_files_are_reported_and_the_rest_imported(
    folder: Path, settings: Settings, capsys: pytest.CaptureFixture[str], fixtures_dir: Path
) -> None:
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    (folder / "empty.bvh").write_bytes(b"")
    orphans = folder / "no-skeleton"
    orphans.mkdir()
    shutil.copy(fixtures_dir / "cmu_02_01_first40.amc", orphans / "05_01.amc")
    code = main(["import", "--data-dir", str(settings.data_dir), "--no-progress", str(folder)])
    assert code == 1
    out = capsys.readouterr().out
    assert "imported 3, skipped 0 as duplicates, failed 3 of 6 clips found" in out
    failed = out.split("failed:\n", 1)[1]
    assert f"{folder / 'broken.bvh'}: " in failed and "line" in failed
    assert f"{folder / 'empty.bvh'}: " in failed and "empty" in failed
    assert f"{orphans / '05_01.amc'}: no .asf skeleton in its folder" in failed
    assert rows(settings, "SELECT count(*) FROM clips") == [(3,)]


def test_labels_from_a_regex_a_tsv_and_the_command_line(
    folder: Path, settings: Settings, tmp_path: Path
) -> None:
    tsv = tmp_path / "labels.tsv"
    tsv.write_text("clip\taction\n02_01\twalk\ncmu_mb_02_01_first41\twalk-mb\n")
    rules = LabelRules.build(
        tsv=tsv, regex=r"^(?P<source>[a-z]+)_(?P<action>[a-z]+)_", fixed=["batch-1"]
    )
    report = run_import(settings, [folder], labels=rules, workers=1)
    assert len(report.imported) == 3 and not report.failed
    labels: dict[str, list[str]] = {}
    for name, label in rows(
        settings,
        "SELECT c.name, l.label FROM clips c JOIN clip_labels l ON l.clip_id = c.id "
        "ORDER BY c.name, l.position",
    ):
        labels.setdefault(name, []).append(label)
    assert [(name, "|".join(values)) for name, values in labels.items()] == [
        ("02_01", "walk|batch-1"),  # the regex finds nothing in 'cmu/02/02_01.amc'
        ("bandai_walk_normal_001_first40", "bandai|walk|batch-1"),
        ("cmu_mb_02_01_first41", "mb|cmu|batch-1"),  # the regex overrides the TSV action
    ]


def test_unusable_label_rules_stop_before_any_work(
    folder: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data_dir = tmp_path / "no-library-yet"
    argv = ["import", "--data-dir", str(data_dir), str(folder)]
    assert main([*argv, "--labels-regex", "(no named group)"]) == 1
    assert "no named group" in capsys.readouterr().err
    assert not (data_dir / "mocap-index.sqlite3").exists()


def test_same_content_twice_in_one_run_is_stored_once(
    folder: Path, settings: Settings, fixtures_dir: Path
) -> None:
    shutil.copy(fixtures_dir / BVH_FIXTURES[0], folder / "copy.bvh")
    report = run_import(settings, [folder], workers=2, batch_size=2)
    assert len(report.imported) == 3 and len(report.duplicates) == 1
    duplicate = report.duplicates[0]
    assert duplicate.clip_name in {"copy", "bandai_walk_normal_001_first40"}
    assert rows(settings, "SELECT count(*) FROM clips") == [(3,)]


def test_nothing_to_import(tmp_path: Path, settings: Settings) -> None:
    (tmp_path / "empty").mkdir()
    report = run_import(settings, [tmp_path / "empty", tmp_path / "missing"])
    assert report.found == 1 and not report.imported
    assert [f.reason for f in report.failed] == ["no such file or folder"]


def test_cmu_data_imports_with_every_skeleton(shared_data: SharedData, settings: Settings) -> None:
    cmu = shared_data("cmu", "asf-amc")
    amc = sorted(cmu.rglob("*.amc"))
    report = run_import(settings, [cmu])
    assert not report.failed, report.failed
    assert len(report.imported) == len(amc)
    used = {skeleton.name for skeleton in report.skeletons()}
    assert {"01.asf", "02.asf", "131.asf", "135.asf"} <= used


def test_a_worker_that_dies_is_replaced_and_its_task_handed_back(
    settings: Settings, fixtures_dir: Path
) -> None:
    clip = (0, "bvh", (str(fixtures_dir / BVH_FIXTURES[0]),))
    pool = WorkerPool(1, settings.parse_limits, None)
    try:
        worker = pool.workers[0]
        task = [clip] * 200  # long enough to be killed while describing it
        pool.submit(worker, task)
        time.sleep(0.1)
        os.kill(worker.process.pid, signal.SIGKILL)
        lost: list = []
        deadline = time.monotonic() + 30
        while not lost and time.monotonic() < deadline:
            _, lost = pool.collect(0.2)
        assert lost == [task]
        assert len(pool.workers) == 1 and pool.workers[0] is not worker
        pool.submit(pool.workers[0], [clip])
        outcomes: list = []
        while not outcomes and time.monotonic() < deadline:
            outcomes, _ = pool.collect(0.2)
        [(number, (status, descriptions, shas))] = outcomes
        assert number == 0 and status == "ok" and descriptions[0].frame_count == 40
        assert len(shas) == 1
    finally:
        pool.close()


def test_a_worker_from_the_fork_server_waits_for_work_however_long(
    settings: Settings, fixtures_dir: Path
) -> None:
    """A worker started by the fork server (a replacement, or any worker once the importing
    process has threads) has the fork server as its parent: it must not take that for its
    importer being gone, and quit, when no task comes within its first poll (a rerun that
    opened a large library first then failed writing to its pipe: BrokenPipeError)."""
    clip = (0, "bvh", (str(fixtures_dir / BVH_FIXTURES[0]),))
    pool = WorkerPool(1, settings.parse_limits, None)
    try:
        killed = pool.workers[0]
        os.kill(killed.process.pid, signal.SIGKILL)
        deadline = time.monotonic() + 30
        while pool.workers[0] is killed and time.monotonic() < deadline:
            pool.collect(0.2)
        replacement = pool.workers[0]
        assert replacement is not killed
        time.sleep(2.5)  # idle past the worker's 1-s poll for orphanhood
        assert replacement.process.is_alive()
        pool.submit(replacement, [clip])
        outcomes: list = []
        while not outcomes and time.monotonic() < deadline:
            outcomes, _ = pool.collect(0.2)
        [(number, (status, _, _))] = outcomes
        assert number == 0 and status == "ok"
    finally:
        pool.close()


def test_a_task_for_a_worker_that_died_since_the_last_collect_is_not_sent(
    settings: Settings, fixtures_dir: Path
) -> None:
    """``submit`` to a worker that died after the last ``collect`` says so (the importer
    keeps the clips pending; they are no culprits) instead of raising BrokenPipeError, and
    the next ``collect`` replaces the worker."""
    clip = (0, "bvh", (str(fixtures_dir / BVH_FIXTURES[0]),))
    pool = WorkerPool(1, settings.parse_limits, None)
    try:
        dead = pool.workers[0]
        os.kill(dead.process.pid, signal.SIGKILL)
        dead.process.join(timeout=30)
        assert pool.submit(dead, [clip]) is False and not dead.tasks
        _, lost = pool.collect(0.2)
        assert lost == [] and pool.workers[0] is not dead
        assert pool.submit(pool.workers[0], [clip]) is True
    finally:
        pool.close()


def _import_glb(
    settings: Settings, folder: Path, fixtures_dir: Path, build: Callable[[Any], bytes]
) -> tuple[Any, Any, list[Any]]:
    """Import ``walk.glb`` built by ``build`` from the CMU BVH fixture's motion: the run, the
    motion and the clips it stored."""
    from app.motion.formats import read_bvh

    folder.mkdir()
    motion = read_bvh((fixtures_dir / "cmu_mb_02_01_first41.bvh").read_bytes())
    (folder / "walk.glb").write_bytes(build(motion))
    done = run_import(settings, [folder], workers=1)
    library = open_library(settings)
    try:
        with library.reads() as session:
            clips = clip_db.get_clips(session, [c.clip_id for c in done.imported])
    finally:
        library.close()
    return done, motion, list(clips.values())


def test_every_animation_of_a_scene_file_is_a_clip_and_a_rerun_skips_them(
    tmp_path: Path, settings: Settings, fixtures_dir: Path
) -> None:
    from tests.motion.gltf_builder import two_animation_glb

    folder = tmp_path / "scenes"
    first, _, clips = _import_glb(settings, folder, fixtures_dir, two_animation_glb)
    assert not first.failed and len(first.imported) == 2
    assert sorted(c.name for c in clips) == ["walk · start", "walk · walk"]
    assert {c.animation for c in clips} == {"walk", "start"}
    assert len({c.content_hash for c in clips}) == 2
    again = run_import(settings, [folder], workers=1)
    assert not again.imported and len(again.duplicates) == 2


def test_a_gltf_beside_its_bin_imports_and_a_missing_bin_is_a_refusal_naming_it(
    tmp_path: Path, settings: Settings, fixtures_dir: Path
) -> None:
    from tests.api.test_scene_uploads import separate_gltf

    vrma = (fixtures_dir / "three_vrm_test.vrma").read_bytes()
    folder = tmp_path / "scenes"
    (folder / "whole" / "buffers").mkdir(parents=True)
    (folder / "broken").mkdir()
    document, binary = separate_gltf(vrma, "buffers/test.bin")
    (folder / "whole" / "test.gltf").write_bytes(document)
    (folder / "whole" / "buffers" / "test.bin").write_bytes(binary)
    outside, _ = separate_gltf(vrma, "../whole/buffers/test.bin")
    (folder / "broken" / "test.gltf").write_bytes(outside)
    result = run_import(settings, [folder], workers=1)
    assert len(result.imported) == 1
    assert [str(f.path.relative_to(folder)) for f in result.failed] == ["broken/test.gltf"]
    assert "outside the document's folder" in result.failed[0].reason


def test_an_animation_that_moves_nothing_is_not_imported(
    tmp_path: Path, settings: Settings, fixtures_dir: Path
) -> None:
    from tests.motion.gltf_builder import with_empty_take

    done, motion, clips = _import_glb(settings, tmp_path / "scenes", fixtures_dir, with_empty_take)
    assert not done.failed and len(done.imported) == 1
    (clip,) = clips
    assert clip.animation == "walk" and clip.frame_count == motion.frame_count


def test_a_take_written_split_over_stacks_is_one_clip(
    tmp_path: Path, settings: Settings, fixtures_dir: Path
) -> None:
    """Blender's per-object stacks (tests/fixtures/split_takes_fbx.py): one clip, the joined
    take; neither part, nor the stack that moves no node of the skeleton, is a clip."""
    folder = tmp_path / "scenes"
    folder.mkdir()
    shutil.copy(fixtures_dir / "cmu_mb_02_01_split.fbx", folder / "walk.fbx")
    done = run_import(settings, [folder], workers=1)
    assert not done.failed and len(done.imported) == 1
    library = open_library(settings)
    try:
        with library.reads() as session:
            (clip,) = clip_db.get_clips(session, [done.imported[0].clip_id]).values()
    finally:
        library.close()
    assert " + " in (clip.animation or "") and clip.frame_count == 41


def test_the_import_saves_no_index_before_the_run_ends(settings: Settings) -> None:
    from app.importer.run import _open_library

    library = _open_library(settings)
    try:
        every = [*library.indexes.values(), *library.window_indexes.values()]
        assert len(every) > len(library.indexes)  # window indexes included
        assert not any(index.autosave for index in every)
    finally:
        library.close()


def test_the_workers_outcomes_are_read_while_a_batch_is_stored(
    tmp_path: Path, settings: Settings, fixtures_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A worker waits once its outcomes fill the pipe, so an import that stopped reading
    them while it stored a batch left the cores idle: the first batch's store is held here
    until every clip has been described and read."""
    from app.importer import run as importer_run
    from app.importer.workers import Outcome
    from app.services import ingest
    from tests.cli.test_import_process import unique_copies

    total = 200
    unique_copies(fixtures_dir / BVH_FIXTURES[0], tmp_path / "clips", total)
    received: list[int] = []
    receive = importer_run._Run.receive

    def counting_receive(run: importer_run._Run, number: int, outcome: Outcome) -> None:
        received.append(number)
        receive(run, number, outcome)

    first_store: list[tuple[int, int]] = []  # (read before it, read while it waited)
    store_many = ingest.store_many

    def held_store_many(library: object, items: list) -> list:
        if not first_store:
            before = len(received)
            deadline = time.monotonic() + 120  # a bound, not a timing: ~2 s on a quiet machine
            while len(received) < total and time.monotonic() < deadline:
                time.sleep(0.02)
            first_store.append((before, len(received) - before))
        return store_many(library, items)  # type: ignore[arg-type]

    monkeypatch.setattr(importer_run._Run, "receive", counting_receive)
    monkeypatch.setattr(ingest, "store_many", held_store_many)
    report = run_import(settings, [tmp_path / "clips"], workers=1, batch_size=16)
    assert len(report.imported) == total and not report.failed
    [(before, during)] = first_store
    assert before < total  # the first batch was stored before the last clip was described
    assert before + during == total
    assert rows(settings, "SELECT count(*) FROM clips") == [(total,)]


def test_with_moments_off_the_import_describes_and_stores_no_windows(
    folder: Path, settings: Settings
) -> None:
    off = settings.model_copy(update={"moments": False})
    report = run_import(off, [folder], workers=1)
    assert len(report.imported) == 3 and not report.failed
    assert rows(off, "SELECT count(*) FROM clip_windows") == [(0,)]
    assert rows(off, "SELECT count(*) FROM clip_descriptors") == [(9,)]  # 3 clips x 3
    assert not list(off.index_dir.glob("windows-*"))
    pool = WorkerPool(1, off.parse_limits, None, windows=False)
    try:
        pool.submit(pool.workers[0], [(0, "bvh", (str(folder / BVH_FIXTURES[0]),))])
        outcomes: list = []
        deadline = time.monotonic() + 30
        while not outcomes and time.monotonic() < deadline:
            outcomes, _ = pool.collect(0.2)
        [(_, (status, descriptions, _))] = outcomes
        assert status == "ok" and descriptions[0].windows is None  # not even described
    finally:
        pool.close()
