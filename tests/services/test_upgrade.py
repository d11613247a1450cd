"""A library written by the previous release keeps working after the upgrade.

``tests/fixtures/library-v1`` was written by mocap-index before descriptor version 2 (schema
0001, every vector version 1). Today's service opens it (migrating the schema), lists and
serves its clips, refuses searches under outdated descriptors with 409 until
``mocap-index reindex`` — run here as the real command — recomputes the vectors from the
stored files; then searches work and find the format twin.
"""

from __future__ import annotations

import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.descriptors import REGISTRY
from tests.conftest import FIXTURES_DIR

OLD_LIBRARY = FIXTURES_DIR / "library-v1"


def _copy_old_library(tmp_path: Path) -> Path:
    data = tmp_path / "data"
    shutil.copytree(OLD_LIBRARY, data)
    return data


def _versions(data: Path) -> set[tuple[str, int]]:
    with sqlite3.connect(data / "mocap-index.sqlite3") as db:
        return set(db.execute("SELECT DISTINCT name, version FROM clip_descriptors"))


def test_a_library_of_the_previous_release_is_upgraded_by_reindex(tmp_path: Path) -> None:
    data = _copy_old_library(tmp_path)
    assert _versions(data) == {(name, 1) for name in REGISTRY}
    settings = Settings(data_dir=data)

    with TestClient(create_app(settings)) as client:
        clips = client.get("/clips").json()["items"]
        names = {clip["name"]: clip["id"] for clip in clips}
        assert set(names) == {
            "bandai_walk_normal_001_first40",
            "cmu_02_01_first40",
            "cmu_mb_02_01_first41",
        }
        twin = names["cmu_02_01_first40"]
        assert client.get(f"/clips/{twin}/file", params={"part": "motion"}).status_code == 200
        for descriptor in REGISTRY:
            answer = client.get("/search", params={"clip": twin, "descriptor": descriptor})
            assert answer.status_code == 409, answer.text
            assert answer.json()["error"] == "descriptor_outdated"
            assert "mocap-index reindex" in answer.json()["detail"]
        upload = (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_bytes()
        by_upload = client.post("/search", files={"file": ("q.bvh", upload)})
        assert by_upload.status_code == 409 and "reindex" in by_upload.json()["detail"]

    command = [sys.executable, "-m", "app.cli", "reindex", "--data-dir", str(data)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    assert "recomputed 3 clips, 0 failed" in done.stdout
    assert _versions(data) == {(name, d.version) for name, d in REGISTRY.items()}

    with TestClient(create_app(settings)) as client:
        health = client.get("/health").json()
        for name, descriptor in REGISTRY.items():
            assert health["indexes"][name]["size"] == 3
            assert health["indexes"][name]["version"] == descriptor.version
        found = client.get("/search", params={"clip": twin, "k": 2}).json()
        assert found["descriptor"] == "motion"
        assert found["results"][0]["name"] == "cmu_mb_02_01_first41"
