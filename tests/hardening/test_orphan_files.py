"""Start-up removes the stored files no clip refers to (a crash between writing and committing,
or between a delete and its file removal) once they are older than the grace; recent ones may
belong to an import that has not committed yet and stay."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from tests.hardening.live import unique_upload


def plant(settings: Settings, data: bytes, *, age: float) -> tuple[str, Path]:
    sha = hashlib.sha256(data).hexdigest()
    path = settings.files_dir / sha[:2] / sha
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    then = time.time() - age
    os.utime(path, (then, then))
    return sha, path


def test_old_unreferenced_files_go_recent_ones_and_used_ones_stay(settings: Settings) -> None:
    with TestClient(create_app(settings)) as client:
        clip = client.post("/clips", files=unique_upload(0)).json()
    used = settings.files_dir.rglob("*")
    used_files = [p for p in used if p.is_file()]
    assert len(used_files) == 1
    old_sha, old = plant(settings, b"left by a crash", age=3600)
    _new_sha, new = plant(settings, b"an import's, not committed yet", age=5)
    temporary = settings.files_dir / old_sha[:2] / f".{old_sha}.123.456.tmp"
    temporary.write_bytes(b"half")
    os.utime(temporary, (time.time() - 3600,) * 2)
    index_tmp = settings.index_dir / ".posture.faiss.123.456.tmp"
    index_tmp.write_bytes(b"half")
    os.utime(index_tmp, (time.time() - 3600,) * 2)
    foreign = settings.files_dir / "README.txt"
    foreign.write_text("not ours: never touched")

    with TestClient(create_app(settings)) as client:  # default grace: 600 s
        assert client.get(f"/clips/{clip['id']}/file").status_code == 200
    assert not old.exists() and not temporary.exists() and not index_tmp.exists()
    assert new.exists() and used_files[0].exists() and foreign.exists()

    no_grace = Settings(data_dir=settings.data_dir, orphan_file_grace_seconds=0)
    with TestClient(create_app(no_grace)) as client:
        assert client.get(f"/clips/{clip['id']}/file").status_code == 200
    assert not new.exists() and used_files[0].exists()
