"""Moments search, cut downloads and the windows' life cycle, through the real app on the
real motion core (small real files from tests/fixtures)."""

from __future__ import annotations

import io
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text

from app.config import Settings
from app.main import create_app
from app.motion.formats import read_asf_amc, read_bvh
from app.services.library import open_library
from app.services.reindex import reindex
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    fixture_bytes,
    fixture_text,
)


def long_take() -> bytes:
    """A 4-s take from the 40-frame Bandai excerpt: forwards, backwards, forwards."""
    text = fixture_text(BANDAI_FIXTURE).replace("\r\n", "\n")
    head, rest = text.split("Frames:")
    frame_time, *lines = rest.split("\n", 2)[1:2] + rest.split("\n")[2:]
    frames = [line for line in lines if line.strip()]
    take = frames + frames[::-1] + frames
    return f"{head}Frames: {len(take)}\n{frame_time}\n" + "\n".join(take) + "\n"


def upload(client: TestClient, data: bytes, name: str, **fields: Any) -> Any:
    response = client.post("/clips", files={"file": (name, data)}, data=fields)
    assert response.status_code in (200, 201), response.text
    return response.json()


def iou(a: tuple[float, float], b: tuple[float, float]) -> float:
    inter = max(0.0, min(a[1], b[1]) - max(a[0], b[0]))
    return inter / (max(a[1], b[1]) - min(a[0], b[0]))


def sql(settings: Settings, statement: str, **params: Any) -> Any:
    """Run one statement on the test's database (SQLite or PostgreSQL); its scalar, if any."""
    engine = create_engine(settings.sqlalchemy_url)
    try:
        with engine.begin() as connection:
            result = connection.execute(text(statement), params)
            return result.scalar() if result.returns_rows else None
    finally:
        engine.dispose()


def window_rows(settings: Settings, clip_id: int | None = None) -> int:
    if clip_id is None:
        return int(sql(settings, "SELECT count(*) FROM clip_windows"))
    return int(sql(settings, "SELECT count(*) FROM clip_windows WHERE clip_id = :c", c=clip_id))


def window_index_sizes(client: TestClient) -> int:
    """How many windows the server's window indexes hold — after checking that where it
    believes each lies (the moments search's in-memory places) is what the database says."""
    from app.db import windows as window_db

    library = client.app.state.library  # type: ignore[attr-defined]
    with library.reads() as session:
        for name, key in library.window_keys.items():
            ids, starts, stops = window_db.load_window_places(session, key)
            places = library.places(name)
            held, held_starts, held_stops = places.find(ids)
            assert held.all() and len(places) == len(ids), name
            np.testing.assert_array_equal(held_starts, starts)
            np.testing.assert_array_equal(held_stops, stops)
            np.testing.assert_array_equal(np.sort(library.window_indexes[name].ids()), ids)
    return sum(library.window_indexes.sizes().values())


@pytest.fixture
def take_client(client: TestClient) -> Iterator[tuple[TestClient, int, int]]:
    take = upload(client, long_take(), "take.bvh", labels="take")
    walk = upload(client, fixture_bytes(BANDAI_FIXTURE), "walk.bvh", labels="walk")
    yield client, take["id"], walk["id"]


def test_upload_stores_windows_and_indexes_them(
    take_client: tuple[TestClient, int, int], settings: Settings
) -> None:
    client, take, walk = take_client
    # 120 frames at 30 fps: 1-s windows every 8 frames and one ending with the clip (13),
    # 2-s every 30 (3), one 4-s.
    assert window_rows(settings, take) == 13 + 3 + 1
    assert window_rows(settings, walk) == 3  # 40 frames: [0, 30), [8, 38), the end's [10, 40)
    assert window_index_sizes(client) == window_rows(settings)


def test_moments_of_a_stored_span(take_client: tuple[TestClient, int, int]) -> None:
    client, take, walk = take_client
    response = client.get("/search/moments", params={"clip": take, "start": 0.0, "end": 1.3})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["query"]["clip"]["id"] == take
    assert (body["query"]["start"], body["query"]["end"]) == (0.0, 1.3)
    assert body["descriptor"] == "motion" and body["k"] == 10
    results = body["results"]
    assert results and set(results[0]) == {
        "id",
        "name",
        "labels",
        "format",
        "start",
        "end",
        "distance",
        "similarity",
    }
    distances = [r["distance"] for r in results]
    assert distances == sorted(distances)
    for r in results:  # nothing overlapping the query span itself
        assert not (r["id"] == take and r["start"] < 1.3 and r["end"] > 0.0)
        assert 0.0 <= r["start"] < r["end"]
    # The same motion: the walk excerpt, and the take's third part (frames 80-120).
    found = {(r["id"], round(r["start"])) for r in results}
    assert (walk, 0) in found
    assert any(r["id"] == take and r["start"] >= 2.5 for r in results)
    per_clip = client.get(
        "/search/moments", params={"clip": take, "start": 0.0, "end": 1.3, "per_clip": 1}
    ).json()["results"]
    assert len({r["id"] for r in per_clip}) == len(per_clip)
    labelled = client.get(
        "/search/moments", params={"clip": take, "start": 0, "end": 1.3, "label": "walk"}
    ).json()["results"]
    assert {r["id"] for r in labelled} == {walk}
    # k = 1 caps a search that has more than one moment to give at one.
    span = {"clip": take, "start": 0.0, "end": 1.3}
    assert len(client.get("/search/moments", params=span).json()["results"]) > 1
    assert len(client.get("/search/moments", params={**span, "k": 1}).json()["results"]) == 1


def test_moment_search_errors_say_what_is_wrong(take_client: tuple[TestClient, int, int]) -> None:
    client, take, _ = take_client
    cases = [
        ({"clip": take, "start": 2.0, "end": 1.0}, "before end"),
        ({"clip": take, "start": 0.0, "end": 9.0}, "outside the clip"),
        ({"clip": take, "start": -1.0, "end": 1.0}, "outside the clip"),
        ({"clip": take, "start": 1.0, "end": 1.5}, "shorter than the shortest window"),
        ({"clip": take, "descriptor": "posture"}, "descriptors with windows"),
        ({"clip": take, "descriptor": "nope"}, "unknown"),
        ({"clip": take, "per_clip": 0}, "per_clip"),
        ({"clip": take, "k": 0}, "k:"),
    ]
    for params, message in cases:
        response = client.get("/search/moments", params=params)
        assert response.status_code == 422, (params, response.text)
        assert response.json()["error"] == "invalid_input"
        assert message in response.json()["detail"], (params, response.text)
    assert client.get("/search/moments", params={"clip": 999}).status_code == 404


def test_cut_bvh_download_has_the_frames_and_finds_its_source_span(
    take_client: tuple[TestClient, int, int],
) -> None:
    client, take, _ = take_client
    response = client.get(f"/clips/{take}/file", params={"start": 1.0, "end": 2.5})
    assert response.status_code == 200, response.text
    assert "take_1.00-2.50s.bvh" in response.headers["content-disposition"]
    cut = read_bvh(response.content)
    whole = read_bvh(long_take())
    assert cut.frame_count == 45
    assert (cut.local_rotations == whole.local_rotations[30:75]).all()
    # Searched by upload (stored nowhere), the cut finds where it came from, first.
    before = client.get("/clips").json()["total"]
    found = client.post("/search/moments", files={"file": ("cut.bvh", response.content)})
    assert found.status_code == 200, found.text
    body = found.json()
    assert body["query"] == {
        "clip": None,
        "start": 0.0,
        "end": pytest.approx(1.5, abs=1e-5),
        "stored_clip": None,
    }
    top = body["results"][0]
    assert top["id"] == take and iou((top["start"], top["end"]), (1.0, 2.5)) >= 0.8
    # It starts where a stored window does: its first part lies on that window, to a frame.
    assert top["start"] == pytest.approx(1.0, abs=0.5 / 30)
    assert client.get("/clips").json()["total"] == before
    # Re-uploaded, it is a clip of its own with exactly those frames.
    stored = upload(client, response.content, "cut.bvh")
    assert stored["frame_count"] == 45
    bad = client.post(
        "/search/moments", params={"start": 1, "end": 0.5}, files={"file": ("c.bvh", b"x")}
    )
    assert bad.status_code == 422


def test_cut_asf_amc_download_is_a_zip_of_the_skeleton_and_the_cut_motion(
    client: TestClient,
) -> None:
    asf, amc = fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE)
    clip = client.post(
        "/clips", files={"skeleton": ("02.asf", asf), "motion": ("02_01.amc", amc)}
    ).json()
    frame_time = clip["frame_time"]
    start, end = 10 * frame_time, 30 * frame_time
    response = client.get(f"/clips/{clip['id']}/file", params={"start": start, "end": end})
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/zip"
    with zipfile.ZipFile(io.BytesIO(response.content)) as archive:
        names = archive.namelist()
        assert names[0] == "02.asf" and names[1].startswith("02_01_") and names[1].endswith(".amc")
        assert archive.read("02.asf") == asf
        cut_amc = archive.read(names[1])
    whole = read_asf_amc(asf, amc)
    cut = read_asf_amc(asf, cut_amc)
    assert cut.frame_count == 20
    assert (cut.local_rotations == whole.local_rotations[10:30]).all()
    motion_only = client.get(
        f"/clips/{clip['id']}/file", params={"start": start, "end": end, "part": "motion"}
    )
    assert motion_only.content == cut_amc
    again = client.post(
        "/clips", files={"skeleton": ("02.asf", asf), "motion": ("cut.amc", cut_amc)}
    )
    assert again.status_code == 201 and again.json()["frame_count"] == 20
    outside = client.get(f"/clips/{clip['id']}/file", params={"start": 0, "end": 99})
    assert outside.status_code == 422 and "outside the clip" in outside.json()["detail"]


def test_delete_removes_the_windows(
    take_client: tuple[TestClient, int, int], settings: Settings
) -> None:
    client, take, walk = take_client
    assert client.delete(f"/clips/{take}").status_code == 204
    assert window_rows(settings, take) == 0
    assert window_index_sizes(client) == window_rows(settings) == window_rows(settings, walk)
    results = client.get("/search/moments", params={"clip": walk}).json()["results"]
    assert all(r["id"] != take for r in results)


def test_window_indexes_are_rebuilt_or_caught_up_at_start(
    settings: Settings, tmp_path: Path
) -> None:
    settings = settings.model_copy(update={"index_refresh_seconds": 0.0})  # check every search
    with TestClient(create_app(settings)) as client:
        take = upload(client, long_take(), "take.bvh")["id"]
        expected = client.get("/search/moments", params={"clip": take, "start": 0, "end": 1.3})
    index_dir = settings.data_dir / "indexes"
    # A crash before the index was saved: an empty index file is caught up from the database.
    (index_dir / "windows-motion-1s.faiss").write_bytes(b"damaged")
    (index_dir / "windows-motion-2s.json").unlink()
    with TestClient(create_app(settings)) as client:
        assert window_index_sizes(client) == window_rows(settings) == 17
        again = client.get("/search/moments", params={"clip": take, "start": 0, "end": 1.3})
        assert again.json() == expected.json()
        # Another process stores a clip: this one finds its windows without a restart.
        library = open_library(settings)
        try:
            from app.services.ingest import ingest
            from app.services.uploads import Upload

            other = ingest(
                library, Upload.from_files(file=("walk.bvh", fixture_bytes(BANDAI_FIXTURE)))
            ).clip.id
        finally:
            library.close()
        found = client.get("/search/moments", params={"clip": take, "start": 0, "end": 1.3})
        assert other in {r["id"] for r in found.json()["results"]}


def test_reindex_rebuilds_the_windows(settings: Settings) -> None:
    with TestClient(create_app(settings)) as client:
        take = upload(client, long_take(), "take.bvh")["id"]
    sql(settings, "DELETE FROM clip_windows")
    library = open_library(settings)
    try:
        assert sum(library.window_indexes.sizes().values()) == 0  # repaired to the database
        report = reindex(library)
        assert report.recomputed == 1 and not report.failed
        assert window_rows(settings, take) == 17
        assert sum(library.window_indexes.sizes().values()) == 17
    finally:
        library.close()


def test_window_indexes_follow_another_process_through_the_feed(settings: Settings) -> None:
    """Deletes and rewritten windows reach a running server's window indexes through the
    change feed (a delete cascades to the windows; a rewrite puts the clip on the feed)."""
    from app.db import windows as window_db
    from app.services.clips import delete_clip

    settings = settings.model_copy(update={"index_refresh_seconds": 0.0})  # check every search
    with TestClient(create_app(settings)) as client:
        take = upload(client, long_take(), "take.bvh")["id"]
        walk = upload(client, fixture_bytes(BANDAI_FIXTURE), "walk.bvh")["id"]
        assert window_index_sizes(client) == 20
        library = open_library(settings)  # another process
        try:
            key = next(k for k in library.window_keys.values() if k.length == 1.0)
            before = sql(settings, "SELECT count(*) FROM clip_changes")
            with library.writes.begin() as session:  # the walk's 1-s windows rewritten
                walk_windows = window_db.load_window_rows(session, key, [walk])[walk]
                starts, stops, vectors = walk_windows
                window_db.put_windows(
                    session,
                    walk,
                    [
                        window_db.NewWindows(
                            "motion",
                            key.version,
                            np.full(len(starts), 1.0),
                            starts,
                            stops,
                            vectors + 1.0,
                        )
                    ],
                )
            assert sql(settings, "SELECT count(*) FROM clip_changes") == before + 1
            delete_clip(library, take)
        finally:
            library.close()
        results = client.get("/search/moments", params={"clip": walk}).json()["results"]
        assert all(r["id"] != take for r in results)
        library = client.app.state.library  # type: ignore[attr-defined]
        assert window_index_sizes(client) == window_rows(settings) == 3
        index = library.window_indexes["windows-motion-1s"]
        held = index.reconstruct_many(index.ids())[1]
        np.testing.assert_allclose(np.sort(held, axis=0), np.sort(vectors + 1.0, axis=0))


def test_moments_off_keeps_no_windows_and_says_so(settings: Settings) -> None:
    """MOCAP_MOMENTS=false (a library too large to keep windows in memory): uploads store
    no windows, moments search answers 409 naming the setting, whole-clip search works;
    turned back on, `reindex` describes the clips stored without windows."""
    off = settings.model_copy(update={"moments": False})
    with TestClient(create_app(off)) as client:
        take = upload(client, long_take(), "take.bvh")["id"]
        walk = upload(client, fixture_bytes(BANDAI_FIXTURE), "walk.bvh")["id"]
        assert window_rows(settings) == 0
        assert client.app.state.library.window_indexes.sizes() == {}  # type: ignore[attr-defined]
        by_clip = client.get("/search/moments", params={"clip": take, "k": 3})
        by_upload = client.post(
            "/search/moments", files={"file": ("walk.bvh", fixture_bytes(BANDAI_FIXTURE))}
        )
        for response in (by_clip, by_upload):
            assert response.status_code == 409, response.text
            body = response.json()
            assert body["error"] == "moments_off" and "MOCAP_MOMENTS" in body["detail"]
        whole = client.get("/search", params={"clip": take, "k": 3})
        assert whole.status_code == 200 and [r["id"] for r in whole.json()["results"]] == [walk]
    assert not list(off.index_dir.glob("windows-*"))

    library = open_library(settings)  # moments on again
    try:
        report = reindex(library)
        assert report.recomputed == 2 and not report.failed
        assert window_rows(settings, take) == 17 and window_rows(settings, walk) == 3
    finally:
        library.close()
    with TestClient(create_app(settings)) as client:
        found = client.get("/search/moments", params={"clip": take, "start": 0, "end": 1.3})
        assert found.status_code == 200, found.text
        assert found.json()["results"]


def test_window_places_come_from_their_file_and_catch_up(settings: Settings) -> None:
    """A server writes where each window lies to a file (mapped, shared by its processes)
    and reads it back at the next start, with the clips changed while it was down read
    again from the database."""
    with TestClient(create_app(settings)) as client:
        take = upload(client, long_take(), "take.bvh")["id"]
        upload(client, fixture_bytes(BANDAI_FIXTURE), "walk.bvh")
    files = sorted(p.name for p in settings.index_dir.glob("windows-*.places.arrays"))
    assert files, "no places file written"
    # While no server runs: another writer deletes a clip and stores one.
    other = open_library(settings)
    try:
        from app.services import clips as clip_service
        from app.services.ingest import ingest
        from app.services.uploads import Upload

        clip_service.delete_clip(other, take)
        ingest(other, Upload.from_files(file=("cut.bvh", long_take()[:-200].encode() + b"\n")))
    finally:
        other.engine.dispose()  # killed: nothing saved
    with TestClient(create_app(settings)) as client:
        assert window_index_sizes(client) == window_rows(settings)  # the places agree too


# -- issue 24: licence filters, collapse=capture, "this file is clip #N", similarity ----------


def test_moments_filters_collapse_and_the_stored_file(
    take_client: tuple[TestClient, int, int],
) -> None:
    client, take, walk = take_client
    # The walk again in another file (one more newline): the same capture twice.
    copy = upload(client, fixture_bytes(BANDAI_FIXTURE) + b"\n", "walk copy.bvh")["id"]
    client.patch(f"/clips/{walk}", json={"licence": "CC BY-NC 4.0"})
    span = {"clip": take, "start": 0.0, "end": 1.3, "k": 10}
    everything = client.get("/search/moments", params=span).json()["results"]
    assert {walk, copy} <= {m["id"] for m in everything}
    assert all(0 <= m["similarity"] <= 100 for m in everything)
    for licence, keeps in (("cc by-nc 4.0", {walk}), ("!CC BY-NC 4.0", {take, copy})):
        kept = [m for m in everything if m["id"] in keeps]
        found = client.get("/search/moments", params={**span, "licence": licence}).json()
        assert found["results"] == kept, licence
    collapsed = client.get("/search/moments", params={**span, "collapse": "capture"}).json()
    ids = [m["id"] for m in collapsed["results"]]
    assert walk in ids and copy not in ids  # the copy is listed with the walk's moment
    first = collapsed["results"][ids.index(walk)]
    assert [(o["id"], o["start"]) for o in first["others"]] == [(copy, first["start"])]
    # Searching with a stored file names it.
    stored = client.post(
        "/search/moments", files={"file": ("w.bvh", fixture_bytes(BANDAI_FIXTURE))}
    )
    assert stored.json()["query"]["stored_clip"] == {"id": walk, "name": "walk"}
    assert stored.json()["results"][0]["id"] in (take, walk, copy)  # the take holds it too
    assert stored.json()["results"][0]["distance"] == 0.0
