"""The clip life cycle over HTTP with the real motion core on the small real files in
tests/fixtures (a Bandai BVH, a CMU MotionBuilder BVH, a CMU ASF + AMC)."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.descriptors import REGISTRY
from tests.api.conftest import stored_blobs
from tests.services.fakes import fake_motion

BANDAI = "bandai_walk_normal_001_first40.bvh"
CMU_BVH = "cmu_mb_02_01_first41.bvh"
ASF, AMC = "cmu_02.asf", "cmu_02_01_first40.amc"


def read(fixtures_dir: Path, name: str) -> bytes:
    return (fixtures_dir / name).read_bytes()


def post_bvh(client: TestClient, fixtures_dir: Path, filename: str, **data: Any) -> Any:
    return client.post(
        "/clips", files={"file": (filename, read(fixtures_dir, filename))}, data=data
    )


def post_asf_amc(client: TestClient, fixtures_dir: Path, **data: Any) -> Any:
    files = {
        "skeleton": (ASF, read(fixtures_dir, ASF)),
        "motion": (AMC, read(fixtures_dir, AMC)),
    }
    return client.post("/clips", files=files, data=data)


def stored_files(settings: Settings) -> list[str]:
    return stored_blobs(settings)


def test_upload_bvh_and_duplicate(client: TestClient, fixtures_dir: Path) -> None:
    response = post_bvh(client, fixtures_dir, BANDAI, labels=["walk, normal", "bandai"])
    assert response.status_code == 201, response.text
    clip = response.json()
    assert response.headers["location"] == f"/clips/{clip['id']}"
    assert clip["name"] == BANDAI.removesuffix(".bvh")
    assert clip["filenames"] == [BANDAI] and clip["format"] == "bvh"
    assert clip["labels"] == ["walk", "normal", "bandai"]
    assert clip["frame_count"] == 40 and clip["joint_count"] > 20
    assert clip["frame_time"] == pytest.approx(1 / 30, rel=1e-3)
    assert clip["duration"] == pytest.approx(40 / 30, rel=1e-3)
    assert clip["skeleton_family"] and clip["lead_in_frames"] >= 0
    assert len(clip["content_hash"]) == 64 and clip["created_at"].endswith("Z")
    assert "descriptors" not in clip

    # The same content again stores nothing new; what it brings is applied (issue #14).
    again = post_bvh(client, fixtures_dir, BANDAI, name="another name")
    assert again.status_code == 200
    assert again.json() == {**clip, "name": "another name", "duplicate": True}
    assert client.get("/clips").json()["total"] == 1


def test_upload_asf_amc(client: TestClient, fixtures_dir: Path) -> None:
    response = post_asf_amc(client, fixtures_dir, name="cmu walk")
    assert response.status_code == 201, response.text
    clip = response.json()
    assert clip["format"] == "asf/amc" and clip["filenames"] == [ASF, AMC]
    assert clip["name"] == "cmu walk" and clip["frame_count"] == 40
    assert post_asf_amc(client, fixtures_dir).json()["id"] == clip["id"]


def test_list_get_patch(client: TestClient, fixtures_dir: Path) -> None:
    a = post_bvh(client, fixtures_dir, BANDAI, labels="walk").json()
    b = post_bvh(client, fixtures_dir, CMU_BVH, labels="walk,cmu").json()
    c = post_asf_amc(client, fixtures_dir, labels="cmu").json()

    page = client.get("/clips", params={"limit": 2}).json()
    assert page["total"] == 3 and page["limit"] == 2 and page["offset"] == 0
    assert [x["id"] for x in page["items"]] == [a["id"], b["id"]]
    rest = client.get("/clips", params={"limit": 2, "offset": 2}).json()
    assert [x["id"] for x in rest["items"]] == [c["id"]]
    cmu = client.get("/clips", params={"label": "cmu"}).json()
    assert cmu["total"] == 2 and [x["id"] for x in cmu["items"]] == [b["id"], c["id"]]

    assert client.get(f"/clips/{a['id']}").json() == a
    full = client.get(f"/clips/{a['id']}", params={"include": "descriptors"}).json()
    assert set(full["descriptors"]) == set(REGISTRY)
    for name, descriptor in REGISTRY.items():
        assert full["descriptors"][name]["version"] == descriptor.version
        assert len(full["descriptors"][name]["vector"]) == descriptor.dimension

    patched = client.patch(f"/clips/{a['id']}", json={"labels": ["cmu", "renamed"]})
    assert patched.status_code == 200
    assert patched.json()["labels"] == ["cmu", "renamed"] and patched.json()["name"] == a["name"]
    renamed = client.patch(f"/clips/{a['id']}", json={"name": "  my walk "}).json()
    assert renamed["name"] == "my walk" and renamed["labels"] == ["cmu", "renamed"]
    assert client.get("/clips", params={"label": "cmu"}).json()["total"] == 3
    assert client.get("/clips", params={"label": "walk"}).json()["total"] == 1


def test_download_returns_the_uploaded_bytes(client: TestClient, fixtures_dir: Path) -> None:
    bvh = post_bvh(client, fixtures_dir, BANDAI).json()
    response = client.get(f"/clips/{bvh['id']}/file")
    assert response.status_code == 200
    assert response.content == read(fixtures_dir, BANDAI)
    assert BANDAI in response.headers["content-disposition"]

    pair = post_asf_amc(client, fixtures_dir).json()
    archive = client.get(f"/clips/{pair['id']}/file")
    assert archive.headers["content-type"] == "application/zip"
    with zipfile.ZipFile(io.BytesIO(archive.content)) as zipped:
        assert zipped.namelist() == [ASF, AMC]
        assert zipped.read(ASF) == read(fixtures_dir, ASF)
        assert zipped.read(AMC) == read(fixtures_dir, AMC)
    for part, name in (("skeleton", ASF), ("motion", AMC)):
        single = client.get(f"/clips/{pair['id']}/file", params={"part": part})
        assert single.content == read(fixtures_dir, name)


def test_delete_removes_row_vectors_and_files(
    client: TestClient, fixtures_dir: Path, settings: Settings
) -> None:
    keep = post_bvh(client, fixtures_dir, BANDAI).json()
    other = post_bvh(client, fixtures_dir, CMU_BVH).json()
    gone = post_asf_amc(client, fixtures_dir).json()
    assert len(stored_files(settings)) == 4
    for name in REGISTRY:
        found = client.get("/search", params={"clip": keep["id"], "descriptor": name}).json()
        assert gone["id"] in [r["id"] for r in found["results"]]

    assert client.delete(f"/clips/{gone['id']}").status_code == 204
    assert client.get(f"/clips/{gone['id']}").status_code == 404
    assert client.get(f"/clips/{gone['id']}/file").status_code == 404
    assert client.delete(f"/clips/{gone['id']}").status_code == 404
    assert len(stored_files(settings)) == 2
    for name in REGISTRY:
        found = client.get("/search", params={"clip": keep["id"], "descriptor": name}).json()
        assert [r["id"] for r in found["results"]] == [other["id"]]
    health = client.get("/health").json()
    assert health["clips"] == 2
    assert all(index["size"] == 2 for index in health["indexes"].values())


def test_search_by_clip_and_by_upload_under_every_descriptor(
    client: TestClient, fixtures_dir: Path
) -> None:
    ids = [
        post_bvh(client, fixtures_dir, BANDAI).json()["id"],
        post_bvh(client, fixtures_dir, CMU_BVH).json()["id"],
        post_asf_amc(client, fixtures_dir).json()["id"],
    ]
    for name in ("posture", "kinetic", *REGISTRY):
        body = client.get("/search", params={"clip": ids[1], "k": 10, "descriptor": name}).json()
        assert body["descriptor"] == name and body["query"]["id"] == ids[1]
        found = [r["id"] for r in body["results"]]
        assert sorted(found) == sorted([ids[0], ids[2]])
        distances = [r["distance"] for r in body["results"]]
        assert distances == sorted(distances) and all(d >= 0 for d in distances)

        upload = {"file": (CMU_BVH, read(fixtures_dir, CMU_BVH))}
        by_upload = client.post("/search", params={"k": 3, "descriptor": name}, files=upload)
        assert by_upload.status_code == 200, by_upload.text
        hits = by_upload.json()["results"]
        assert hits[0]["id"] == ids[1] and hits[0]["distance"] == pytest.approx(0, abs=1e-5)
        assert len(hits) == 3
    # the default descriptor is motion, and GET /descriptors says so
    default = client.get("/search", params={"clip": ids[0]}).json()
    assert default["descriptor"] == "motion" and default["k"] == 10
    assert client.get("/descriptors").json()["default"] == "motion"


def test_unreadable_upload_leaves_no_row_vector_or_file(
    client: TestClient, fixtures_dir: Path, settings: Settings
) -> None:
    broken = read(fixtures_dir, BANDAI).replace(b"OFFSET", b"OFFSETS", 1)
    response = client.post("/clips", files={"file": ("broken.bvh", broken)})
    assert response.status_code == 422
    body = response.json()
    assert body["error"] == "parse_error"
    assert "broken.bvh" in body["detail"] and "line " in body["detail"]
    bad_amc = client.post(
        "/clips",
        files={
            "skeleton": (ASF, read(fixtures_dir, ASF)),
            "motion": ("bad.amc", b":FULLY-SPECIFIED\n1\nroot x y z\n"),
        },
    )
    assert bad_amc.status_code == 422 and "bad.amc" in bad_amc.json()["detail"]
    assert client.get("/health").json()["clips"] == 0
    assert stored_files(settings) == []
    assert all(i["size"] == 0 for i in client.get("/health").json()["indexes"].values())


@pytest.fixture
def limited_client(settings: Settings) -> Iterator[TestClient]:
    limited = settings.model_copy(update={"max_frames": 30, "max_joints": 20})
    with TestClient(create_app(limited)) as client:
        yield client


def test_frame_and_joint_limits(limited_client: TestClient, fixtures_dir: Path) -> None:
    response = post_bvh(limited_client, fixtures_dir, BANDAI)
    assert response.status_code == 422
    assert response.json()["error"] == "limit_exceeded"
    response = post_asf_amc(limited_client, fixtures_dir)
    assert response.status_code == 422 and response.json()["error"] == "limit_exceeded"
    assert limited_client.get("/clips").json()["total"] == 0


def test_warnings_and_the_joint_mapping_are_shown(client: TestClient, fixtures_dir: Path) -> None:
    clean = post_bvh(client, fixtures_dir, CMU_BVH).json()
    assert clean["warnings"] == []
    assert "mapping" not in client.get(f"/clips/{clean['id']}").json()
    both = client.get(f"/clips/{clean['id']}", params={"include": "descriptors,mapping"}).json()
    assert set(both["descriptors"]) == set(REGISTRY)
    mapping = both["mapping"]
    assert mapping["joints"]["l_elbow"] == {"joint": "LeftForeArm", "how": "name"}
    assert mapping["joints"]["head"]["joint"] == "Head_end"
    assert "head" in mapping["end_sites"] and mapping["mirrored"] is False
    assert mapping["pose"] == "rest pose"

    # A file whose last frame was cut short (a broken download) goes in, saying so.
    text = read(fixtures_dir, BANDAI).decode()
    cut = client.post("/clips", files={"file": ("cut.bvh", text[:-500].encode())})
    assert cut.status_code == 201, cut.text
    assert cut.json()["frame_count"] == 39
    assert [w for w in cut.json()["warnings"] if "cut short" in w]
    assert client.get(f"/clips/{cut.json()['id']}").json()["warnings"] == cut.json()["warnings"]

    unknown = client.get(f"/clips/{clean['id']}", params={"include": "mapping,bones"})
    assert unknown.status_code == 422 and "bones" in unknown.json()["detail"]


@pytest.mark.parametrize(
    ("query", "named"),
    [
        ("licence=!", "licence: "),
        ("licence=%20,!%20", "licence: "),
        ("q=%20%20", "q: "),
        ("label=&licence=!", "label, licence: "),
        ("label=,", "label: "),
        ("", "label: "),
    ],
)
def test_an_empty_selection_to_delete_names_the_parameters_given(
    fake_client: TestClient, query: str, named: str
) -> None:
    stored = fake_client.post("/clips", files={"file": ("a.bvh", fake_motion([1, 0, 0]))})
    assert stored.status_code == 201, stored.text
    for confirm in ("", "&confirm=true"):
        response = fake_client.delete(f"/clips?{query}{confirm}")
        assert response.status_code == 422, response.text
        assert response.json()["error"] == "invalid_input"
        assert response.json()["detail"].startswith(named), response.json()
        assert "clips to delete" in response.json()["detail"]
    assert fake_client.get("/clips").json()["total"] == 1
