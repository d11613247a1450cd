"""POST /inspect: the animations of an uploaded file, to choose one before storing it; an
unknown animation name is its own error (`unknown_animation`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.motion.formats import read_bvh
from tests.motion.gltf_builder import two_animation_glb

CMU_BVH = "cmu_mb_02_01_first41.bvh"


@pytest.fixture
def glb(fixtures_dir: Path) -> tuple[str, bytes]:
    return ("walk.glb", two_animation_glb(read_bvh((fixtures_dir / CMU_BVH).read_bytes())))


def test_inspect_lists_a_files_animations(ui_client: TestClient, glb: tuple[str, bytes]) -> None:
    response = ui_client.post("/inspect", files={"file": glb})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["format"] == "gltf" and body["filenames"] == ["walk.glb"]
    names = [(a["name"], a["frame_count"], a["selected"]) for a in body["animations"]]
    assert names == [("walk", 41, True), ("start", 10, False)]  # the longest is the default
    assert body["frame_count"] == 41
    assert body["animations"][0]["duration"] == pytest.approx(body["duration"], abs=0.05)
    chosen = ui_client.post("/inspect", files={"file": glb}, data={"animation": "start"}).json()
    assert [a["selected"] for a in chosen["animations"]] == [False, True]
    assert chosen["frame_count"] == 10
    # Nothing was stored.
    assert ui_client.get("/clips").json()["total"] == 0


def test_inspect_a_single_motion_file(ui_client: TestClient, fixtures_dir: Path) -> None:
    path = fixtures_dir / CMU_BVH
    body = ui_client.post("/inspect", files={"file": (path.name, path.read_bytes())}).json()
    assert body["format"] == "bvh" and body["animations"] == []
    assert body["frame_count"] == 41


def test_an_unknown_animation_is_its_own_error(
    ui_client: TestClient, glb: tuple[str, bytes]
) -> None:
    """Everywhere a file is read: storing, searching, previewing, inspecting."""
    for route in ("/inspect", "/clips", "/search", "/skeleton"):
        response = ui_client.post(route, files={"file": glb}, data={"animation": "run"})
        assert response.status_code == 422, (route, response.text)
        body = response.json()
        assert body["error"] == "unknown_animation", (route, body)
        assert "'run'" in body["detail"] and "'walk', 'start'" in body["detail"]
        assert "'walk.glb'" in body["detail"]  # which file
