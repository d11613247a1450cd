"""Every hostile upload gets its 4xx in the one error shape, quickly, leaves nothing behind,
and the service stays healthy (the real app and motion core, over HTTP).

The cases and their answers: ``expected.json`` beside this file (written with the corpus by
``make_corpus.py``), plus the big cases :func:`make_corpus.big_cases` builds at test time.
"""

from __future__ import annotations

import gzip
import json
import resource
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from tests.hostile import make_corpus
from tests.hostile.make_corpus import Case

HERE = Path(__file__).resolve().parent
TIME_LIMIT = 5.0  # seconds for any one hostile upload, on a busy 2-core CI machine
MEMORY_LIMIT_MB = 1024  # growth of this process' peak RSS over all the big cases


SMALL = make_corpus.load_cases(make_corpus.EXPECTED)
BIG = make_corpus.big_cases()
# Routes that read an uploaded query file: each gives the verdict the upload gets.
SEARCHES = ("/search", "/search/moments")


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, Settings]]:
    """One real app (real parsers and descriptors) for every case of the module."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("hostile") / "data")
    with TestClient(create_app(settings)) as client:
        yield client, settings


def post(client: TestClient, url: str, case: Case) -> tuple[Any, float]:
    started = time.monotonic()
    response = client.post(url, files=case.parts)
    return response, time.monotonic() - started


def check_answer(response: Any, elapsed: float, case: Case) -> None:
    assert response.status_code == case.status, (case.name, response.text[:300])
    assert response.headers["content-type"].startswith("application/json")
    body = response.json()
    assert set(body) == {"error", "detail"}, body
    assert body["error"] == case.error, (case.name, body)
    assert isinstance(body["detail"], str) and body["detail"]
    assert case.detail in body["detail"], (case.name, body["detail"])
    assert len(body["detail"]) < 1000, "a hostile file must not flood the message"
    assert elapsed < TIME_LIMIT, f"{case.name} took {elapsed:.1f} s"


def check_healthy_and_empty(client: TestClient, settings: Settings) -> None:
    health = client.get("/health")
    assert health.status_code == 200 and health.json()["status"] == "ok"
    assert health.json()["clips"] == 0
    assert all(index["size"] == 0 for index in health.json()["indexes"].values())
    files = settings.files_dir
    assert not files.exists() or not any(p.is_file() for p in files.rglob("*")), "left a file"


def test_the_committed_corpus_is_what_the_generator_writes(tmp_path: Path) -> None:
    expected = json.loads((HERE / "expected.json").read_text())
    assert [c.name for c in make_corpus.small_cases()] == list(expected)
    for case in make_corpus.small_cases():
        for role, (_filename, data) in case.parts.items():
            assert (HERE / expected[case.name]["parts"][role]["path"]).read_bytes() == data


def test_the_corpus_covers_the_issue() -> None:
    names = {c.name for c in SMALL} | {c.name for c in BIG}
    wanted = {
        "empty",
        "binary_garbage",
        "not_utf8",
        "truncated_hierarchy",
        "truncated_motion",
        "too_few_values",
        "too_many_values",
        "nan",
        "inf",
        "overflow",
        "frames_zero",
        "frames_negative",
        "frames_more",
        "frames_fewer",
        "frame_time_zero",
        "frame_time_negative",
        "frame_time_absurd",
        "channels_count",
        "unknown_channel",
        "duplicate_joint",
        "nesting_10000",
        "joints_100000",
        "line_10mb_frame",
        "amc_unknown_bone",
        "asf_unknown_unit",
        "gzip_file",
        "zip_file",
        "fbx_garbage",
        "fbx_truncated",
        "glb_garbage",
        "glb_inf",
        "glb_no_skeleton",
        "glb_no_animation",
        "gltf_parent_uri",
        "gltf_absolute_uri",
        "gltf_http_uri",
        "sentinel_1e308",
        "number_200k_digits_frame",
        "number_30k_digits_offset",
        "number_200k_digits_amc",
    }
    assert wanted <= names, wanted - names


@pytest.mark.parametrize("case", SMALL, ids=[c.name for c in SMALL])
def test_small_hostile_upload(live: tuple[TestClient, Settings], case: Case) -> None:
    client, settings = live
    if case.status == 201:
        # Repaired, not refused: stored with a warning that says what was done, and searched
        # with by both search routes (one reader, one verdict).
        response, elapsed = post(client, "/clips", case)
        assert response.status_code == 201, (case.name, response.text[:300])
        assert any(case.detail in w for w in response.json()["warnings"]), response.json()
        assert elapsed < TIME_LIMIT
        assert client.delete(f"/clips/{response.json()['id']}").status_code == 204
        for url in SEARCHES:
            assert post(client, url, case)[0].status_code == 200, (case.name, url)
        check_healthy_and_empty(client, settings)
        return
    # Refused alike by the upload and by both search routes.
    for url in ("/clips", *SEARCHES):
        response, elapsed = post(client, url, case)
        check_answer(response, elapsed, case)
    check_healthy_and_empty(client, settings)


@pytest.mark.parametrize("case", BIG, ids=[c.name for c in BIG])
def test_big_hostile_upload(live: tuple[TestClient, Settings], case: Case) -> None:
    client, settings = live
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    response, elapsed = post(client, "/clips", case)
    check_answer(response, elapsed, case)
    if case.name.startswith("number_"):  # the tokens that froze a search: every route
        for url in SEARCHES:
            check_answer(*post(client, url, case), case)
    grown = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - before
    assert grown < MEMORY_LIMIT_MB, f"{case.name}: peak memory grew by {grown:.0f} MB"
    check_healthy_and_empty(client, settings)


def test_compressed_request_bodies_are_refused(live: tuple[TestClient, Settings]) -> None:
    client, settings = live
    body = gzip.compress(b"--xx\r\n" * 1000, mtime=0)
    response = client.post(
        "/clips",
        content=body,
        headers={"content-type": "multipart/form-data; boundary=xx", "content-encoding": "gzip"},
    )
    assert response.status_code == 415
    assert response.json()["error"] == "unsupported_media_type"
    assert "compressed" in response.json()["detail"]
    check_healthy_and_empty(client, settings)


def test_the_real_fixture_still_goes_in_after_all_that(
    live: tuple[TestClient, Settings], fixtures_dir: Path
) -> None:
    client, _settings = live
    data = (fixtures_dir / "cmu_mb_02_01_first41.bvh").read_bytes()
    response = client.post("/clips", files={"file": ("walk.bvh", data)})
    assert response.status_code == 201, response.text
    assert client.delete(f"/clips/{response.json()['id']}").status_code == 204
