"""Settings: defaults, MOCAP_* variables, and the command line's overrides."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from app.cli import build_parser, main, settings_from
from app.config import Settings
from app.db.migrate import head_revision


def test_defaults(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    settings = Settings()
    assert settings.data_dir == tmp_path / "data"
    assert settings.sqlalchemy_url == f"sqlite:///{tmp_path}/data/mocap-index.sqlite3"
    assert settings.files_dir == tmp_path / "data" / "files"
    assert settings.index_dir == tmp_path / "data" / "indexes"
    assert settings.max_upload_bytes == 256 * 1024 * 1024  # a ten-minute take as BVH text
    assert settings.max_k == 1000 and settings.host == "127.0.0.1" and settings.port == 8000
    limits = settings.parse_limits
    assert (limits.max_frames, limits.max_joints, limits.max_depth) == (100_000, 512, 128)
    # ten minutes at 120 fps of a 98-joint rig (end sites included) fit, nine values a joint
    assert limits.max_values == 64_000_000 >= 72_000 * 98 * 9


def test_environment_variables(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOCAP_DATA_DIR", str(tmp_path / "elsewhere"))
    monkeypatch.setenv("MOCAP_MAX_UPLOAD_BYTES", "1234")
    monkeypatch.setenv("MOCAP_MAX_FRAMES", "99")
    settings = Settings()
    assert settings.data_dir == tmp_path / "elsewhere"
    assert settings.max_upload_bytes == 1234 and settings.parse_limits.max_frames == 99
    monkeypatch.setenv("MOCAP_DATABASE_URL", "postgresql://u@db/mocap")
    assert Settings().sqlalchemy_url == "postgresql://u@db/mocap"
    monkeypatch.setenv("MOCAP_MAX_K", "0")
    with pytest.raises(ValidationError):
        Settings()


def test_command_line_overrides_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MOCAP_PORT", "9000")
    monkeypatch.setenv("MOCAP_HOST", "0.0.0.0")
    args = build_parser().parse_args(["serve", "--host", "127.0.0.2", "--data-dir", str(tmp_path)])
    settings = settings_from(args)
    assert settings.host == "127.0.0.2" and settings.port == 9000
    assert settings.data_dir == tmp_path


def test_migrate_and_reindex_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["migrate", "--data-dir", str(tmp_path)]) == 0
    assert (tmp_path / "mocap-index.sqlite3").is_file()
    assert f"revision {head_revision()}" in capsys.readouterr().out
    assert main(["reindex", "--data-dir", str(tmp_path)]) == 0
    assert "recomputed 0 clips" in capsys.readouterr().out
    assert {p.name for p in (tmp_path / "indexes").glob("*.faiss")} >= {"posture.faiss"}


def test_bad_setting_on_the_command_line(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOCAP_MAX_UPLOAD_BYTES", "lots")
    assert main(["migrate", "--data-dir", str(tmp_path)]) == 2


def test_clip_codes_are_float32_or_sq8(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert Settings(data_dir=tmp_path).clip_codes == "float32"
    monkeypatch.setenv("MOCAP_CLIP_CODES", "sq8")
    assert Settings(data_dir=tmp_path).clip_codes == "sq8"
    monkeypatch.setenv("MOCAP_CLIP_CODES", "fp16")
    with pytest.raises(ValidationError):
        Settings(data_dir=tmp_path)
