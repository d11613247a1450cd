"""``mocap-index fill-synthetic``: synthetic clips around the real ones, marked as such."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from app.cli import main
from app.config import Settings
from app.importer import run_import
from app.services.library import open_library
from app.services.search import search_by_clip_id


def test_fill_to_a_count_with_ivf_indexes(
    settings: Settings,
    fixtures_dir: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    # 9 real clips to start from: 2 BVH, 1 ASF/AMC, 5 FBX, 1 VRM animation.
    run_import(settings, [fixtures_dir], workers=1)
    monkeypatch.setenv("MOCAP_INDEX_AUTO_THRESHOLD", "2000")
    argv = ["fill-synthetic", "--count", "3000", "--data-dir", str(settings.data_dir)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "added 2991 synthetic clips" in out and "holds 3000 clips" in out
    assert "posture ivf" in out
    assert main(argv) == 0  # already full: nothing added
    assert "added 0 synthetic clips" in capsys.readouterr().out

    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    try:
        synthetic = db.execute(
            "SELECT count(*), count(DISTINCT content_hash), min(name) FROM clips "
            "WHERE format = 'synthetic'"
        ).fetchone()
        labelled = db.execute(
            "SELECT count(*) FROM clip_labels WHERE label = 'synthetic'"
        ).fetchone()[0]
        files = db.execute(
            "SELECT count(*) FROM clip_files f JOIN clips c ON c.id = f.clip_id "
            "WHERE c.format = 'synthetic'"
        ).fetchone()[0]
    finally:
        db.close()
    assert synthetic == (2991, 2991, "synthetic-0000010") and labelled == 2991 and files == 0
    meta = json.loads((settings.data_dir / "indexes" / "posture.json").read_text())
    assert meta["kind"] == "ivf" and meta["count"] == 3000 and meta["nprobe"] >= 1

    library = open_library(Settings(data_dir=settings.data_dir, index_auto_threshold=2000))
    try:
        assert {index.kind for index in library.indexes.values()} == {"ivf"}
        # Synthetic clips gather around the real ones: a real clip's neighbours are synthetic.
        query, hits = search_by_clip_id(library, 1, "posture", 5, label=None)
        assert query.format == "bvh" and len(hits) == 5
        assert all(hit.clip.labels == ("synthetic",) for hit in hits)
        only_real = search_by_clip_id(library, 1, "posture", 5, label="nonexistent")[1]
        assert only_real == []
    finally:
        library.close()


def test_synthetic_clips_copy_the_windows_of_real_ones(
    settings: Settings, fixtures_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run_import(settings, [fixtures_dir], workers=1)
    argv = ["fill-synthetic", "--count", "50", "--data-dir", str(settings.data_dir)]
    assert main(argv) == 0
    assert "windows-motion-1s flat" in capsys.readouterr().out
    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    try:
        per_clip = db.execute(
            "SELECT c.format, count(w.id) FROM clips c LEFT JOIN clip_windows w "
            "ON w.clip_id = c.id GROUP BY c.id"
        ).fetchall()
        total = db.execute("SELECT count(*) FROM clip_windows").fetchone()[0]
    finally:
        db.close()
    assert all(count >= 1 for _, count in per_clip) and len(per_clip) == 50
    library = open_library(settings)
    try:
        assert sum(library.window_indexes.sizes().values()) == total
    finally:
        library.close()
