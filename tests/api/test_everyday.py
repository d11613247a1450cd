"""Issue #14 over HTTP: label filters, duplicates, source/licence, bulk delete, one code for a
bad parameter, clips without files, /health (fake motion core: vectors chosen here)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from app.config import Settings
from app.db import clips as clip_db
from app.db import vectors as vector_db
from app.main import create_app
from app.services.ingest import ingest
from app.services.library import open_library
from app.services.uploads import Upload
from tests.conftest import new_sqlite_settings
from tests.services.fakes import FakeDescriber, fake_motion


def upload(client: TestClient, stem: str, posture: list[float], **data: Any) -> Any:
    return client.post("/clips", files={"file": (f"{stem}.bvh", fake_motion(posture))}, data=data)


def stored(client: TestClient, name: str, posture: list[float], labels: list[str]) -> int:
    response = upload(client, name, posture, labels=labels)
    assert response.status_code == 201, response.text
    clip_id: int = response.json()["id"]
    return clip_id


def store_labelled(client: TestClient) -> dict[str, int]:
    return {
        "walk_happy": stored(client, "walk_happy", [0, 0, 0], ["walk", "happy"]),
        "walk_sad": stored(client, "walk_sad", [1, 0, 0], ["Walk", "sad"]),
        "run_happy": stored(client, "run_happy", [2, 0, 0], ["run", "HAPPY"]),
        "idle": stored(client, "idle", [3, 0, 0], []),
    }


@pytest.fixture
def labelled(fake_client: TestClient) -> dict[str, int]:
    return store_labelled(fake_client)


Library = tuple[TestClient, dict[str, int]]


def shared_library(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    fill: Callable[[TestClient], dict[str, int]],
) -> Iterator[Library]:
    """One library per backend (``request.param``) filled by ``fill``, for a module's tests
    that only read it: a new library for each case of their parameters was most of this
    file's time (each case a new app and database, then the uploads)."""
    data_dir = tmp_path_factory.mktemp("shared") / "data"
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_cluster").new_database()
        settings = Settings(data_dir=data_dir, database_url=url)
    else:
        migrated = request.getfixturevalue("migrated_sqlite_file")
        settings = new_sqlite_settings(data_dir, migrated)
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        yield client, fill(client)


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def labelled_library(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Library]:
    """:func:`store_labelled`'s four clips, read by every case of the tests using it."""
    yield from shared_library(request, tmp_path_factory, store_labelled)


def names(page: dict[str, Any]) -> list[str]:
    return [clip["name"] for clip in page["items"]]


# -- 6, 7: label filters: all of them, any case, empty = none --------------------------------


@pytest.mark.parametrize(
    "query, expected",
    [
        ("label=walk&label=happy", ["walk_happy"]),
        ("label=walk,happy", ["walk_happy"]),
        ("label=WALK&label=happy,", ["walk_happy"]),
        ("label=happy", ["walk_happy", "run_happy"]),
        ("label=walk", ["walk_happy", "walk_sad"]),
        ("label=", ["walk_happy", "walk_sad", "run_happy", "idle"]),
        ("label=&label=%20,", ["walk_happy", "walk_sad", "run_happy", "idle"]),
        ("label=walk&label=run", []),
    ],
)
def test_label_filters_mean_all_of_them_in_any_case(
    labelled_library: Library, query: str, expected: list[str]
) -> None:
    fake_client, labelled = labelled_library
    for route in ("/clips", "/library/clips"):
        response = fake_client.get(f"{route}?{query}")
        assert response.status_code == 200, response.text
        assert names(response.json()) == expected, route
        assert response.json()["total"] == len(expected)
    search = fake_client.get(f"/search?clip={labelled['idle']}&k=10&{query}")
    assert search.status_code == 200, search.text
    assert sorted(h["name"] for h in search.json()["results"]) == sorted(
        n for n in expected if n != "idle"
    )


def test_label_filter_on_upload_search(fake_client: TestClient, labelled: dict[str, int]) -> None:
    response = fake_client.post(
        "/search?label=Happy,walk&k=10",
        files={"file": ("q.bvh", fake_motion([0, 0, 0.5]))},
    )
    assert response.status_code == 200, response.text
    assert [h["name"] for h in response.json()["results"]] == ["walk_happy"]


def test_labels_are_stored_once_whatever_their_case(fake_client: TestClient) -> None:
    response = upload(fake_client, "x", [0, 0, 9], labels=[" Walk , Happy ,,walk", "HAPPY"])
    assert response.status_code == 201
    clip = response.json()
    assert clip["labels"] == ["Walk", "Happy"]
    patched = fake_client.patch(f"/clips/{clip['id']}", json={"labels": ["a", "A", " b ,B"]})
    assert patched.json()["labels"] == ["a", "b"]
    counts = {
        row["label"].lower(): row["count"] for row in fake_client.get("/library/labels").json()
    }
    assert counts == {"a": 1, "b": 1}


def test_label_counts_merge_spellings(fake_client: TestClient, labelled: dict[str, int]) -> None:
    counts = {
        row["label"].lower(): row["count"] for row in fake_client.get("/library/labels").json()
    }
    assert counts == {"walk": 2, "happy": 2, "sad": 1, "run": 1}


def test_label_filter_is_documented(fake_client: TestClient) -> None:
    spec = fake_client.get("/openapi.json").json()
    for path, method in (("/clips", "get"), ("/search", "get"), ("/search", "post")):
        params = {p["name"]: p for p in spec["paths"][path][method]["parameters"]}
        text = params["label"]["description"]
        assert "all of them" in text and "case-insensitively" in text, path


def test_label_migration_index_serves_the_filter(engine: Engine) -> None:
    # The case-insensitive filter must stay an index lookup (1M clips: bench/bench_search.py).
    with engine.connect() as connection:
        if engine.dialect.name == "postgresql":
            # PostgreSQL chooses by table statistics (a seq scan on a tiny table): ask for the
            # index to be preferred, as it is once the table is large.
            connection.exec_driver_sql("SET enable_seqscan = off")
            plan = connection.exec_driver_sql(
                "EXPLAIN SELECT clip_id FROM clip_labels WHERE label_key = 'walk'"
            ).all()
        else:
            plan = connection.exec_driver_sql(
                "EXPLAIN QUERY PLAN SELECT clip_id FROM clip_labels WHERE label_key = 'walk'"
            ).all()
    assert any("ix_clip_labels_label_key_clip_id" in str(row) for row in plan), plan


# -- 10: a duplicate upload applies what it brings -----------------------------------------


def test_duplicate_upload_adds_labels_and_renames(fake_client: TestClient) -> None:
    first = upload(fake_client, "dup", [5, 5, 5], labels=["walk"]).json()
    again = upload(fake_client, "dup", [5, 5, 5], labels=["WALK", "happy"], name="happy walk")
    assert again.status_code == 200
    body = again.json()
    assert body["duplicate"] is True and body["id"] == first["id"]
    assert body["labels"] == ["walk", "happy"] and body["name"] == "happy walk"
    assert fake_client.get(f"/clips/{first['id']}").json()["labels"] == ["walk", "happy"]
    assert (
        "duplicate" not in first and "duplicate" not in fake_client.get("/clips").json()["items"][0]
    )
    plain = upload(fake_client, "dup", [5, 5, 5])
    assert plain.status_code == 200 and plain.json()["name"] == "happy walk"


def test_duplicate_upload_needs_write_access(tmp_path: Any) -> None:
    from app.main import create_app

    settings = Settings(data_dir=tmp_path / "data", api_key="s3cret")
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        files = {"file": ("k.bvh", fake_motion([1, 2, 3]))}
        keyed = {"X-API-Key": "s3cret"}
        assert client.post("/clips", files=files, headers=keyed).status_code == 201
        refused = client.post("/clips", files=files, data={"labels": ["new"]})
        assert refused.status_code == 401
        assert client.get("/clips", headers=keyed).json()["items"][0]["labels"] == []


# -- 11: missing-part messages -------------------------------------------------------------


def test_missing_part_messages(fake_client: TestClient) -> None:
    alone = fake_client.post("/clips", files={"skeleton": ("02.asf", b"x")})
    assert alone.status_code == 422
    assert alone.json()["detail"] == (
        "field 'motion': the .asf skeleton must come with an .amc 'motion'"
    )
    alone = fake_client.post("/clips", files={"motion": ("02_01.amc", b"x")})
    assert alone.json()["detail"] == (
        "field 'skeleton': the .amc motion must come with its .asf 'skeleton'"
    )


# -- 12: a clip without stored files -------------------------------------------------------


def synthetic_clip(engine: Engine) -> int:
    with Session(engine) as session, session.begin():
        return clip_db.insert_clip(
            session,
            clip_db.NewClip(
                name="synthetic-1",
                format="synthetic",
                content_hash="f" * 64,
                frame_count=10,
                frame_time=0.1,
                duration=1.0,
                joint_count=0,
                skeleton_family="synthetic",
                lead_in_frames=0,
                labels=("synthetic",),
                files=(),
                vectors={"posture": vector_db.StoredVector(1, np.zeros(3, np.float32))},
            ),
        )


def test_clip_without_files_answers_404_not_500(fake_client: TestClient, engine: Engine) -> None:
    clip_id = synthetic_clip(engine)
    for path in (f"/clips/{clip_id}/skeleton", f"/clips/{clip_id}/file"):
        response = fake_client.get(path)
        assert response.status_code == 404, path
        assert response.json()["error"] == "no_stored_file"
        assert "synthetic clip" in response.json()["detail"]


# -- 13: bulk delete by label --------------------------------------------------------------


def test_bulk_delete_by_label(fake_client: TestClient, labelled: dict[str, int]) -> None:
    unconfirmed = fake_client.delete("/clips?label=Happy")
    assert unconfirmed.status_code == 422
    assert "would delete 2 clips" in unconfirmed.json()["detail"]
    assert fake_client.get("/clips").json()["total"] == 4
    nothing = fake_client.delete("/clips?label=&confirm=true")
    assert nothing.status_code == 422 and nothing.json()["error"] == "invalid_input"
    done = fake_client.delete("/clips?label=Happy&confirm=true")
    assert done.status_code == 200
    assert done.json() == {"deleted": 2, "labels": ["Happy"]}
    assert names(fake_client.get("/clips").json()) == ["walk_sad", "idle"]
    hits = fake_client.get(f"/search?clip={labelled['idle']}&k=10").json()["results"]
    assert [h["name"] for h in hits] == ["walk_sad"]


def test_bulk_delete_needs_the_key(tmp_path: Any) -> None:
    from app.main import create_app

    settings = Settings(data_dir=tmp_path / "data", api_key="s3cret")
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        assert client.delete("/clips?label=x&confirm=true").status_code == 401
        bad = client.delete("/clips?label=x&confirm=true", headers={"X-API-Key": "no"})
        assert bad.status_code == 403
        ok = client.delete("/clips?label=x&confirm=true", headers={"X-API-Key": "s3cret"})
        assert ok.status_code == 200 and ok.json()["deleted"] == 0


# -- 14: source and licence ----------------------------------------------------------------


def test_source_and_licence(fake_client: TestClient) -> None:
    response = upload(
        fake_client, "cc", [7, 7, 7], source=" https://mocap.cs.cmu.edu ", licence="free to use"
    )
    clip = response.json()
    assert (clip["source"], clip["licence"]) == ("https://mocap.cs.cmu.edu", "free to use")
    got = fake_client.get(f"/clips/{clip['id']}").json()
    assert (got["source"], got["licence"]) == ("https://mocap.cs.cmu.edu", "free to use")
    patched = fake_client.patch(f"/clips/{clip['id']}", json={"licence": "CC BY 4.0"}).json()
    assert (patched["source"], patched["licence"]) == ("https://mocap.cs.cmu.edu", "CC BY 4.0")
    cleared = fake_client.patch(f"/clips/{clip['id']}", json={"source": None}).json()
    assert cleared["source"] is None and cleared["licence"] == "CC BY 4.0"
    # read through the search path's own SQL too
    other = upload(fake_client, "other", [7, 7, 8]).json()
    query = fake_client.get(f"/search?clip={clip['id']}").json()["query"]
    assert query["licence"] == "CC BY 4.0" and other["source"] is None
    too_long = upload(fake_client, "long", [1, 1, 1], licence="x" * 501)
    assert too_long.status_code == 422 and "licence" in too_long.json()["detail"]


# -- 4: results tell same-named clips apart ------------------------------------------------


def test_hits_carry_format_and_file_names(fake_client: TestClient) -> None:
    query = stored(fake_client, "q", [0, 0, 0], [])
    bvh = stored(fake_client, "02_04", [1, 0, 0], [])
    amc = fake_client.post(
        "/clips",
        files={"skeleton": ("02.asf", b"asf"), "motion": ("02_04.amc", fake_motion([2, 0, 0]))},
    ).json()["id"]
    hits = fake_client.get(f"/search?clip={query}").json()["results"]
    assert [(h["id"], h["name"], h["format"], h["filenames"]) for h in hits] == [
        (bvh, "02_04", "bvh", ["02_04.bvh"]),
        (amc, "02_04", "asf/amc", ["02.asf", "02_04.amc"]),
    ]


# -- 15: one code for a bad parameter ------------------------------------------------------


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def one_clip_library(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Library]:
    """A library of one clip (id 1), read by every case of the test below."""
    yield from shared_library(
        request, tmp_path_factory, lambda client: {"one": stored(client, "one", [0, 0, 0], [])}
    )


@pytest.mark.parametrize(
    "path",
    [
        "/search?clip=1&k=0",
        "/search?clip=1&k=abc",
        "/search?clip=abc",
        "/search?clip=1&k=2.5",
        "/search?clip=1&descriptor=foo",
        "/clips?limit=0",
        "/clips?offset=-1",
        "/clips/abc",
    ],
)
def test_one_code_for_a_bad_parameter(one_clip_library: Library, path: str) -> None:
    fake_client, _ = one_clip_library
    response = fake_client.get(path)
    assert response.status_code == 422
    assert response.json()["error"] == "invalid_input", response.json()


def test_bad_parameter_messages(fake_client: TestClient, fixtures_dir: Any) -> None:
    assert fake_client.get("/clips?offset=-1").json()["detail"] == "offset: must be ≥ 0, got -1"
    clip = stored(fake_client, "one", [0, 0, 0], [])
    both = fake_client.post(
        f"/search?clip={clip}", files={"file": ("q.bvh", fake_motion([0, 0, 0]))}
    )
    assert both.status_code == 422
    assert both.json() == {
        "error": "invalid_input",
        "detail": "clip: give a clip id or a file, not both",
    }
    part = fake_client.get(f"/clips/{clip}/file?part=skeleton")
    assert part.status_code == 422
    assert part.json()["detail"].startswith(f"part: clip {clip} is a single BVH file")


# -- 16: /health tells the truth -----------------------------------------------------------


def test_health_sees_clips_another_process_stored(
    fake_client: TestClient, settings: Settings
) -> None:
    stored(fake_client, "here", [0, 0, 0], [])
    other = open_library(settings, describer=FakeDescriber())
    try:
        for i in range(3):
            ingest(other, Upload.from_files(file=(f"o{i}.bvh", fake_motion([i, 1, 1]))))
    finally:
        other.close()
    health = fake_client.get("/health").json()
    assert health["clips"] == 4
    assert health["indexes"]["posture"] == {"size": 4, "dimension": 3, "version": 1, "missing": 0}


def test_health_missing_counts_clips_without_a_vector(
    fake_client: TestClient, engine: Engine
) -> None:
    stored(fake_client, "here", [0, 0, 0], [])
    synthetic_clip(engine)  # has a posture vector, no kinetic one
    health = fake_client.get("/health").json()
    assert health["clips"] == 2
    assert health["indexes"]["posture"]["missing"] == 0
    assert health["indexes"]["posture"]["size"] == 2
    assert health["indexes"]["kinetic"]["missing"] == 1


# -- issue 24, item 20: small things that were wrong ---------------------------------------


def test_every_route_refuses_a_query_parameter_it_does_not_take(fake_client: TestClient) -> None:
    clip = stored(fake_client, "one", [0, 0, 0], [])
    spec = fake_client.get("/openapi.json").json()
    checked = 0
    for path, methods in spec["paths"].items():
        for method in methods:
            url = path.replace("{clip_id}", str(clip))
            response = fake_client.request(method.upper(), f"{url}?name=walk")
            assert response.status_code == 422, (method, path, response.text)
            body = response.json()
            assert body["error"] == "invalid_input", (method, path)
            assert body["detail"].startswith("name: unknown query parameter"), body
            checked += 1
    assert checked >= 15
    # The message names what the route takes; a known parameter still works.
    detail = fake_client.get("/clips?name=walk").json()["detail"]
    assert "label" in detail and "limit" in detail
    assert fake_client.get("/clips?limit=5").status_code == 200
    assert fake_client.get("/clips").json()["total"] == 1  # nothing was deleted meanwhile


def test_joint_count_leaves_out_end_sites(client: TestClient, fixtures_dir: Any) -> None:
    from app.motion.formats import read_bvh

    path = fixtures_dir / "bandai_walk_normal_001_first40.bvh"
    skeleton = read_bvh(path.read_text()).skeleton
    joints = int((~skeleton.end_site).sum())
    assert 0 < joints < skeleton.joint_count  # the file has end sites
    clip = client.post("/clips", files={"file": (path.name, path.read_bytes())}).json()
    assert clip["joint_count"] == joints


def test_animations_stored_before_count_seconds_as_the_clip_does() -> None:
    # Rows written before: "duration" = first to last key ((n - 1) / rate).
    old = '[{"name": "walk", "frame_count": 121, "duration": 5.0, "selected": true}]'
    (walk,) = clip_db.decode_animations(old) or ()
    assert walk.duration == pytest.approx(121 / 24)
    record = clip_db.AnimationRecord("run", 10, 10 / 30, False)
    assert clip_db.decode_animations(clip_db.encode_animations([record])) == (record,)


def test_a_fresh_library_says_so_once(settings: Settings, caplog: pytest.LogCaptureFixture) -> None:
    import logging

    caplog.set_level(logging.INFO)
    open_library(settings, describer=FakeDescriber()).close()
    fresh = [r for r in caplog.records if "new library" in r.getMessage()]
    assert len(fresh) == 1 and fresh[0].levelno == logging.INFO
    assert not [r for r in caplog.records if "rebuilt" in r.getMessage()]
    caplog.clear()
    open_library(settings, describer=FakeDescriber()).close()  # the files are there now
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.INFO]
    assert not [message for message in said if "index" in message], said


# -- issue 24, items 12-14: licence filters, one search box, bulk labels -------------------


def store_licensed(fake_client: TestClient) -> dict[str, int]:
    def add(name: str, posture: list[float], licence: str | None, **extra: Any) -> int:
        data = {"licence": licence} if licence else {}
        response = upload(fake_client, name, posture, **data, **extra)
        assert response.status_code == 201, response.text
        clip_id: int = response.json()["id"]
        return clip_id

    return {
        "cc0_walk": add("cc0_walk", [0, 0, 1], "CC0", labels=["walk"], source="studio A"),
        "nc_walk": add("nc_walk", [0, 0, 2], "CC BY-NC 4.0", labels=["walk"]),
        "nc_run": add("nc_run", [0, 0, 3], "cc by-nc 4.0", labels=["run"]),
        "by_jump": add("by_jump", [0, 0, 4], "CC BY 4.0", labels=["jump"], source="Studio B"),
        "unknown": add("unknown", [0, 0, 5], None),
    }


@pytest.fixture
def licensed(fake_client: TestClient) -> dict[str, int]:
    return store_licensed(fake_client)


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def licensed_library(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[Library]:
    """:func:`store_licensed`'s five clips, read by every case of the tests using it."""
    yield from shared_library(request, tmp_path_factory, store_licensed)


@pytest.mark.parametrize(
    "query, expected",
    [
        ("licence=CC0", ["cc0_walk"]),
        ("licence=cc%20by-nc%204.0", ["nc_walk", "nc_run"]),
        ("licence=CC0,CC%20BY%204.0", ["cc0_walk", "by_jump"]),
        ("licence=CC0&licence=CC%20BY%204.0", ["cc0_walk", "by_jump"]),
        ("licence=!CC%20BY-NC%204.0", ["cc0_walk", "by_jump", "unknown"]),
        ("licence=!cc0,!CC%20BY-NC%204.0", ["by_jump", "unknown"]),
        ("licence=CC0,CC%20BY%204.0&licence=!CC0", ["by_jump"]),
        ("licence=&licence=%20", ["cc0_walk", "nc_walk", "nc_run", "by_jump", "unknown"]),
        ("licence=!CC%20BY-NC%204.0&label=walk", ["cc0_walk"]),
    ],
)
def test_licence_filters_on_the_list_and_both_searches(
    fake_client: TestClient, licensed: dict[str, int], query: str, expected: list[str]
) -> None:
    listed = fake_client.get(f"/clips?{query}")
    assert listed.status_code == 200, listed.text
    assert names(listed.json()) == expected and listed.json()["total"] == len(expected)
    # A filtered search is the unfiltered ranking restricted to the clips the filter keeps.
    probe = upload(fake_client, "probe", [0, 0, 0], licence="probe").json()["id"]
    everything = fake_client.get(f"/search?clip={probe}&k=10").json()["results"]
    kept = [h["name"] for h in everything if h["name"] in expected]
    searched = fake_client.get(f"/search?clip={probe}&k=10&{query}")
    assert [h["name"] for h in searched.json()["results"]] == kept
    for k in range(1, len(kept) + 1):
        top = fake_client.get(f"/search?clip={probe}&k={k}&{query}").json()["results"]
        assert [h["name"] for h in top] == kept[:k]
    keeps = set(names(fake_client.get(f"/clips?{query}").json()))  # the probe too, maybe
    query_file = {"file": ("q.bvh", fake_motion([0, 0, 0.1]))}
    unfiltered = fake_client.post("/search?k=10", files=query_file).json()["results"]
    by_file = fake_client.post(f"/search?k=10&{query}", files=query_file).json()["results"]
    assert [h["name"] for h in by_file] == [h["name"] for h in unfiltered if h["name"] in keeps]


def test_licence_filter_is_documented(fake_client: TestClient) -> None:
    spec = fake_client.get("/openapi.json").json()
    for path, method in (("/clips", "get"), ("/search", "get"), ("/search", "post")):
        params = {p["name"]: p for p in spec["paths"][path][method]["parameters"]}
        assert "`!`" in params["licence"]["description"], path


@pytest.mark.parametrize(
    "q, expected",
    [
        ("walk", ["cc0_walk", "nc_walk"]),  # names and labels
        ("WALK studio", ["cc0_walk"]),  # words ANDed, any case, source
        ("studio", ["cc0_walk", "by_jump"]),
        ("nc_walk.bvh", ["nc_walk"]),  # file names
        ("by-nc", ["nc_walk", "nc_run"]),  # licence
        ("jump 4.0", ["by_jump"]),
        ("100%", []),  # % and _ are plain characters
        ("  ", ["cc0_walk", "nc_walk", "nc_run", "by_jump", "unknown"]),
    ],
)
def test_one_search_box_finds_text_anywhere(
    licensed_library: Library, q: str, expected: list[str]
) -> None:
    fake_client, _ = licensed_library
    response = fake_client.get("/clips", params={"q": q})
    assert response.status_code == 200, response.text
    assert names(response.json()) == expected


def test_sorting_the_list(fake_client: TestClient) -> None:
    for name, frames in (("b", 30), ("A", 10), ("c", 20)):
        motion = fake_motion([frames, 0, 0], frames=frames)
        assert fake_client.post("/clips", files={"file": (f"{name}.bvh", motion)}).is_success

    def order(sort: str) -> list[str]:
        response = fake_client.get("/clips", params={"sort": sort})
        assert response.status_code == 200, response.text
        return names(response.json())

    assert order("id") == ["b", "A", "c"] == order("created_at")
    assert order("-created_at") == ["c", "A", "b"] == order("-id")
    assert order("name") == ["A", "b", "c"] and order("-name") == ["c", "b", "A"]
    assert order("frame_count") == ["A", "c", "b"] == order("duration")
    assert order("-frame_count") == ["b", "c", "A"]
    page = fake_client.get("/clips", params={"sort": "name", "limit": 1, "offset": 1}).json()
    assert names(page) == ["b"] and page["total"] == 3
    bad = fake_client.get("/clips", params={"sort": "size"})
    assert bad.status_code == 422 and "sort: unknown 'size'" in bad.json()["detail"]


def labels_by_name(client: TestClient) -> dict[str, list[str]]:
    return {c["name"]: c["labels"] for c in client.get("/clips").json()["items"]}


def test_bulk_labels_by_ids_label_licence_or_text(
    fake_client: TestClient, licensed: dict[str, int]
) -> None:
    ids = [licensed["cc0_walk"], licensed["nc_run"]]
    done = fake_client.post("/clips/labels", json={"ids": ids, "add": ["Todo", "todo, keep"]})
    assert done.status_code == 200, done.text
    assert done.json() == {"matched": 2, "changed": 2, "added": ["Todo", "keep"], "removed": []}
    labels = labels_by_name(fake_client)
    assert labels["cc0_walk"] == ["walk", "Todo", "keep"] and labels["nc_run"] == [
        "run",
        "Todo",
        "keep",
    ]
    # Again: nothing changes (a label a clip carries in any case is not added twice).
    again = fake_client.post("/clips/labels", json={"ids": ids, "add": ["TODO"]}).json()
    assert again["matched"] == 2 and again["changed"] == 0
    # By label and licence (all given must hold), removing in any case.
    removed = fake_client.post(
        "/clips/labels", json={"label": ["todo"], "licence": ["!CC0"], "remove": ["TODO"]}
    ).json()
    assert (removed["matched"], removed["changed"]) == (1, 1)
    assert labels_by_name(fake_client)["nc_run"] == ["run", "keep"]
    # By the search box's text; then every clip.
    texted = fake_client.post("/clips/labels", json={"q": "studio", "add": ["studio"]}).json()
    assert (texted["matched"], texted["changed"]) == (2, 2)
    every = fake_client.post("/clips/labels", json={"all": True, "remove": ["keep"]}).json()
    assert (every["matched"], every["changed"]) == (5, 2)
    labels = labels_by_name(fake_client)
    assert labels["by_jump"] == ["jump", "studio"] and labels["cc0_walk"] == [
        "walk",
        "Todo",
        "studio",
    ]
    # Searches filter by the new labels at once.
    found = fake_client.get("/clips?label=studio").json()
    assert sorted(names(found)) == ["by_jump", "cc0_walk"]
    # PATCH still replaces a clip's labels.
    patched = fake_client.patch(f"/clips/{licensed['by_jump']}", json={"labels": ["only"]})
    assert patched.json()["labels"] == ["only"]


@pytest.mark.parametrize(
    "body, message",
    [
        ({"add": ["x"]}, "name the clips"),
        ({"ids": [1]}, "add, remove"),
        ({"ids": [1], "add": ["x" * 101]}, "over 100 characters"),
        ({"ids": [1], "add": ["x"], "colour": "red"}, "colour"),
        ({"ids": "1", "add": ["x"]}, "ids"),
    ],
)
def test_bulk_labels_say_what_is_wrong(
    licensed_library: Library, body: dict[str, Any], message: str
) -> None:
    fake_client, _ = licensed_library
    response = fake_client.post("/clips/labels", json=body)
    assert response.status_code == 422, response.text
    assert response.json()["error"] == "invalid_input"
    assert message in response.json()["detail"]


def test_bulk_labels_keep_the_label_limit(fake_client: TestClient) -> None:
    many = [f"l{i}" for i in range(99)]
    clip = upload(fake_client, "full", [1, 2, 3], labels=many).json()["id"]
    refused = fake_client.post("/clips/labels", json={"ids": [clip], "add": ["a", "b"]})
    assert refused.status_code == 422 and "more than 100 labels" in refused.json()["detail"]
    assert len(fake_client.get(f"/clips/{clip}").json()["labels"]) == 99  # all or nothing


def test_bulk_labels_need_the_key(tmp_path: Any) -> None:
    from app.main import create_app

    settings = Settings(data_dir=tmp_path / "data", api_key="s3cret")
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        body = {"all": True, "add": ["x"]}
        assert client.post("/clips/labels", json=body).status_code == 401
        assert (
            client.post("/clips/labels", json=body, headers={"X-API-Key": "no"}).status_code == 403
        )
        ok = client.post("/clips/labels", json=body, headers={"X-API-Key": "s3cret"})
        assert ok.status_code == 200 and ok.json()["matched"] == 0


def test_bulk_delete_by_ids_licence_or_text(
    fake_client: TestClient, licensed: dict[str, int]
) -> None:
    ask = fake_client.delete("/clips?licence=cc%20by-nc%204.0")
    assert ask.status_code == 422 and "would delete 2 clips" in ask.json()["detail"]
    done = fake_client.delete("/clips?licence=cc%20by-nc%204.0&q=run&confirm=true")
    assert done.json()["deleted"] == 1
    by_id = fake_client.delete(
        f"/clips?id={licensed['unknown']}&id={licensed['cc0_walk']}&confirm=true"
    )
    assert by_id.json()["deleted"] == 2
    assert names(fake_client.get("/clips").json()) == ["nc_walk", "by_jump"]
    nothing = fake_client.delete("/clips?confirm=true")
    assert nothing.status_code == 422 and nothing.json()["error"] == "invalid_input"


def test_bulk_selections_refuse_ids_no_clip_can_have(fake_client: TestClient) -> None:
    for body in ({"ids": [2**63], "add": ["x"]}, {"ids": [-1, 0], "add": ["x"]}):
        response = fake_client.post("/clips/labels", json=body)
        assert response.status_code == 422 and "is no clip id" in response.json()["detail"]
    response = fake_client.delete(f"/clips?id={2**64}&confirm=true")
    assert response.status_code == 422 and response.json()["error"] == "invalid_input"


@pytest.mark.parametrize("param", ["q", "licence", "label"])
def test_filters_with_control_characters_never_fail(fake_client: TestClient, param: str) -> None:
    stored(fake_client, "one", [0, 0, 0], [])
    for route in ("/clips", "/search?clip=1"):
        response = fake_client.get(route, params={param: "a\x00b"})
        assert response.status_code in (200, 422), (route, response.text)


def test_labels_with_a_nul_character_are_refused(fake_client: TestClient) -> None:
    clip = stored(fake_client, "one", [0, 0, 0], [])
    for response in (
        fake_client.post("/clips/labels", json={"all": True, "add": ["a\x00"]}),
        fake_client.patch(f"/clips/{clip}", json={"labels": ["a\x00"]}),
    ):
        assert response.status_code == 422 and "NUL" in response.json()["detail"]
