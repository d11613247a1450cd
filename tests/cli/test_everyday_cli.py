"""Issue #14 on the command line: --version, serve's addresses, delete --label, import's
--label-columns, both regex spellings, duplicates given new labels, fill-synthetic's help."""

from __future__ import annotations

import shutil
import sqlite3
from importlib.metadata import version
from pathlib import Path

import pytest

from app.cli import main
from app.config import Settings
from tests.api.test_restart import running_server

FIXTURE = "bandai_walk_normal_001_first40.bvh"


def labels_of(settings: Settings) -> dict[str, list[str]]:
    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    try:
        rows = db.execute(
            "SELECT c.name, l.label FROM clips c LEFT JOIN clip_labels l ON l.clip_id = c.id "
            "ORDER BY c.name, l.position"
        ).fetchall()
        found: dict[str, list[str]] = {}
        for name, label in rows:
            found.setdefault(name, [])
            if label is not None:
                found[name].append(label)
        return found
    finally:
        db.close()


def test_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"mocap-index {version('mocap-index')}"


def test_serve_prints_the_ui_address(tmp_path: Path) -> None:
    log = tmp_path / "serve.log"
    with running_server(tmp_path / "data", log) as client:
        assert client.get("/").status_code == 200
        base = str(client.base_url).rstrip("/")
    text = log.read_text()
    assert f"web UI at {base}/\n" in text and f"API docs at {base}/docs" in text


@pytest.fixture
def cmu_folder(tmp_path: Path, fixtures_dir: Path) -> Path:
    """Two clips named like CMU's, and a labels table with a free-text description."""
    folder = tmp_path / "cmu"
    folder.mkdir()
    shutil.copy(fixtures_dir / "cmu_mb_02_01_first41.bvh", folder / "02_01.bvh")
    shutil.copy(fixtures_dir / FIXTURE, folder / "05_02.bvh")
    (folder / "labels.tsv").write_text(
        "clip\tcoarse\tfine\tdescription\tlicence\n"
        "02_01\twalk\tWalk\twalk, slow and steady across the room\tfree for any use\n"
        "05_02\tdance\tballet\tballet - pirouette\t\n"
    )
    return folder


def test_import_leaves_free_text_columns_out(
    settings: Settings, cmu_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import", "--no-progress", "--workers", "1", "--data-dir", str(settings.data_dir)]
    assert main([*argv, "--labels-tsv", str(cmu_folder / "labels.tsv"), str(cmu_folder)]) == 0
    assert "left out (free text): description" in capsys.readouterr().err
    assert labels_of(settings) == {"02_01": ["walk"], "05_02": ["dance", "ballet"]}
    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    licences = dict(db.execute("SELECT name, licence FROM clips").fetchall())
    db.close()
    assert licences == {"02_01": "free for any use", "05_02": None}


def test_import_label_columns_and_duplicates_get_new_labels(
    settings: Settings, cmu_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import", "--no-progress", "--workers", "1", "--data-dir", str(settings.data_dir)]
    assert main([*argv, str(cmu_folder)]) == 0
    assert labels_of(settings) == {"02_01": [], "05_02": []}
    capsys.readouterr()
    tsv = ["--labels-tsv", str(cmu_folder / "labels.tsv"), "--label-columns", "fine,description"]
    assert main([*argv, *tsv, str(cmu_folder)]) == 0
    out = capsys.readouterr().out
    assert "skipped 2 as duplicates (2 given new labels, source or licence)" in out
    assert labels_of(settings)["02_01"] == ["Walk", "slow and steady across the room"]
    # JavaScript's named-group spelling works here too; nothing new the second time
    regex = ["--labels-regex", r"(?<subject>\d+)_\d+"]
    assert main([*argv, *regex, str(cmu_folder)]) == 0
    assert "(2 given new labels, source or licence)" in capsys.readouterr().out
    assert labels_of(settings)["05_02"] == ["ballet", "ballet - pirouette", "05"]
    assert main([*argv, *regex, str(cmu_folder)]) == 0
    assert "skipped 2 as duplicates, failed 0" in capsys.readouterr().out


def test_import_label_columns_must_exist(
    settings: Settings, cmu_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import", "--no-progress", "--data-dir", str(settings.data_dir)]
    tsv = ["--labels-tsv", str(cmu_folder / "labels.tsv"), "--label-columns", "mood"]
    assert main([*argv, *tsv, str(cmu_folder)]) == 1
    assert "--label-columns: no column 'mood'" in capsys.readouterr().err


def test_delete_by_label(
    settings: Settings, cmu_folder: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = ["--data-dir", str(settings.data_dir)]
    imported = ["import", "--no-progress", "--workers", "1", *data, "--label", "Session-1"]
    assert main([*imported, str(cmu_folder)]) == 0
    capsys.readouterr()
    assert main(["delete", "--label", "session-1", *data]) == 1
    assert "would delete 2 clips labelled session-1 (of 2); add --yes" in capsys.readouterr().out
    assert len(labels_of(settings)) == 2
    assert main(["delete", "--label", "session-1", "--yes", *data]) == 0
    assert "deleted 2 clips labelled session-1; 0 left" in capsys.readouterr().out
    assert labels_of(settings) == {}
    assert not [p for p in settings.files_dir.rglob("*") if p.is_file()]
    assert main(["delete", "--label", " ", "--yes", *data]) == 2


def test_fill_synthetic_help_says_use_another_data_dir(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        main(["fill-synthetic", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "use a separate --data-dir" in text
    assert "mocap-index delete --label synthetic --yes" in text


# -- issue 24: --source / --licence for a whole import; exit codes on a re-run --------------


def notes_of(settings: Settings) -> dict[str, tuple[str | None, str | None]]:
    db = sqlite3.connect(settings.data_dir / "mocap-index.sqlite3")
    try:
        return {n: (s, li) for n, s, li in db.execute("SELECT name, source, licence FROM clips")}
    finally:
        db.close()


def test_import_gives_every_clip_a_source_and_licence_unless_its_row_does(
    settings: Settings, cmu_folder: Path
) -> None:
    argv = ["import", "--no-progress", "--workers", "1", "--data-dir", str(settings.data_dir)]
    notes = ["--source", " CMU mocap ", "--licence", "CC0"]
    tsv = ["--labels-tsv", str(cmu_folder / "labels.tsv")]
    assert main([*argv, *notes, *tsv, str(cmu_folder)]) == 0
    assert notes_of(settings) == {
        "02_01": ("CMU mocap", "free for any use"),  # its TSV row's licence wins
        "05_02": ("CMU mocap", "CC0"),
    }
    # A re-run gives duplicates what it brings (US spelling of the flag too).
    assert main([*argv, "--license", "CC BY 4.0", str(cmu_folder)]) == 0
    assert notes_of(settings)["05_02"] == ("CMU mocap", "CC BY 4.0")


@pytest.fixture
def folder_with_a_bad_file(tmp_path: Path, fixtures_dir: Path) -> Path:
    folder = tmp_path / "takes"
    folder.mkdir()
    shutil.copy(fixtures_dir / FIXTURE, folder / "good.bvh")
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n")  # cut short
    (folder / "lonely.amc").write_text(":FULLY-SPECIFIED\n1\nroot 0 0 0 0 0 0\n")  # no .asf
    return folder


def test_a_rerun_over_known_unreadable_files_exits_0(
    settings: Settings, folder_with_a_bad_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["import", "--no-progress", "--workers", "1", "--data-dir", str(settings.data_dir)]
    folder = str(folder_with_a_bad_file)
    assert main([*argv, folder]) == 1  # first report of the two refusals
    first = capsys.readouterr().out
    assert "imported 1" in first and "failed 2 of 3" in first and "refused before" not in first
    assert main([*argv, folder]) == 0  # nothing new: the same two refusals
    again = capsys.readouterr().out
    assert "failed 2 (2 refused before) of 3" in again
    assert "broken.bvh" in again and "(refused before)" in again
    assert main([*argv, "--strict", folder]) == 1
    capsys.readouterr()
    # Changed bytes are a new failure; a file that imports now is forgotten.
    (folder_with_a_bad_file / "broken.bvh").write_text("HIERARCHY\nROOT Hip\n{\n")
    assert main([*argv, folder]) == 1
    assert "failed 2 (1 refused before)" in capsys.readouterr().out
    shutil.copy(folder_with_a_bad_file / "good.bvh", folder_with_a_bad_file / "broken.bvh")
    assert main([*argv, folder]) == 0
    remembered = (settings.data_dir / "import-refusals.json").read_text()
    assert "lonely.amc" in remembered and "broken.bvh" not in remembered
