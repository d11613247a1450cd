"""Search semantics over HTTP with vectors chosen by the test (fake motion core)."""

from __future__ import annotations

import itertools

import numpy as np
from fastapi.testclient import TestClient

from tests.services.fakes import fake_motion

# posture vectors; clip i is stored as "c{i}" and labelled "even"/"odd"
POINTS = [[0, 0, 0], [3, 4, 0], [1, 0, 0], [0, 0, 2], [10, 0, 0], [0, -1, 0]]


def upload(client: TestClient, posture: list[float], name: str, labels: list[str]) -> int:
    response = client.post(
        "/clips",
        files={"file": (f"{name}.bvh", fake_motion(posture, kinetic=[len(name), 0]))},
        data={"labels": labels},
    )
    assert response.status_code == 201, response.text
    clip_id: int = response.json()["id"]
    return clip_id


def library(client: TestClient) -> list[int]:
    return [
        upload(client, p, f"c{i}", ["even" if i % 2 == 0 else "odd"]) for i, p in enumerate(POINTS)
    ]


def expected(query: int, ids: list[int], among: set[int] | None = None) -> list[tuple[int, float]]:
    q = np.asarray(POINTS[query], float)
    rows = [
        (ids[i], float(np.linalg.norm(np.asarray(p, float) - q)))
        for i, p in enumerate(POINTS)
        if i != query and (among is None or ids[i] in among)
    ]
    return sorted(rows, key=lambda r: r[1])


def results(body: dict[str, object]) -> list[tuple[int, float]]:
    return [(r["id"], r["distance"]) for r in body["results"]]  # type: ignore[attr-defined, index]


def test_search_by_clip_is_exact_and_excludes_the_query(fake_client: TestClient) -> None:
    ids = library(fake_client)
    body = fake_client.get("/search", params={"clip": ids[0], "k": 3}).json()
    assert body["descriptor"] == "posture" and body["k"] == 3
    assert body["query"]["id"] == ids[0] and body["query"]["name"] == "c0"
    got = results(body)
    want = expected(0, ids)[:3]
    assert [i for i, _ in got] == [i for i, _ in want]
    np.testing.assert_allclose([d for _, d in got], [d for _, d in want], rtol=1e-6)
    # Euclidean, not squared: c1 = (3, 4, 0) is at distance 5 from c0
    full = dict(results(fake_client.get("/search", params={"clip": ids[0], "k": 10}).json()))
    assert full[ids[1]] == 5.0
    first = body["results"][0]
    assert set(first) == {
        "id",
        "name",
        "labels",
        "format",
        "filenames",
        "skeleton_family",
        "distance",
        "similarity",
    } and first["labels"] == ["even"]


def test_fewer_than_k_only_when_the_library_is_smaller(fake_client: TestClient) -> None:
    ids = library(fake_client)
    for k in (1, 4, 5, 6, 1000):
        got = results(fake_client.get("/search", params={"clip": ids[2], "k": k}).json())
        assert len(got) == min(k, len(ids) - 1)
        assert ids[2] not in [i for i, _ in got]


def test_label_filter_is_exact(fake_client: TestClient) -> None:
    ids = library(fake_client)
    odd = {ids[i] for i in range(1, len(ids), 2)}
    body = fake_client.get("/search", params={"clip": ids[0], "k": 10, "label": "odd"}).json()
    assert results(body) == [(i, d) for i, d in expected(0, ids, odd)]
    # the query's own label: the query itself is still excluded
    even = fake_client.get("/search", params={"clip": ids[0], "k": 10, "label": "even"}).json()
    assert [i for i, _ in results(even)] == [ids[2], ids[4]]
    none = fake_client.get("/search", params={"clip": ids[0], "label": "missing"}).json()
    assert none["results"] == []


def test_other_descriptor(fake_client: TestClient) -> None:
    ids = library(fake_client)
    body = fake_client.get("/search", params={"clip": ids[0], "descriptor": "kinetic", "k": 10})
    assert body.status_code == 200 and body.json()["descriptor"] == "kinetic"
    # kinetic vector is (len(name), 0): every other "c<i>" name has length 2, distance 0
    assert {d for _, d in results(body.json())} == {0.0}


def test_search_by_upload_excludes_nothing_and_stores_nothing(fake_client: TestClient) -> None:
    ids = library(fake_client)
    same = ("query.bvh", fake_motion(POINTS[3], kinetic=[2, 0]))
    response = fake_client.post("/search?k=2", files={"file": same}, data={"labels": "q"})
    assert response.status_code == 200, response.text
    body = response.json()
    assert "id" not in body["query"] and body["query"]["name"] == "query"
    assert body["query"]["labels"] == ["q"] and body["query"]["filenames"] == ["query.bvh"]
    assert results(body)[0] == (ids[3], 0.0)
    assert len(body["results"]) == 2
    assert fake_client.get("/clips").json()["total"] == len(ids)
    kinetic = fake_client.post("/search?descriptor=kinetic&k=100", files={"file": same}).json()
    assert len(kinetic["results"]) == len(ids)


def test_deleted_clip_is_gone_from_every_index(fake_client: TestClient) -> None:
    ids = library(fake_client)
    assert fake_client.delete(f"/clips/{ids[2]}").status_code == 204
    for descriptor, query in itertools.product(("posture", "kinetic"), (ids[0], ids[5])):
        body = fake_client.get(
            "/search", params={"clip": query, "k": 100, "descriptor": descriptor}
        ).json()
        assert ids[2] not in [i for i, _ in results(body)]
        assert len(body["results"]) == len(ids) - 2
    health = fake_client.get("/health").json()
    assert health["clips"] == len(ids) - 1
    assert {n: i["size"] for n, i in health["indexes"].items()} == {
        "posture": len(ids) - 1,
        "kinetic": len(ids) - 1,
    }


def test_descriptors_and_health(fake_client: TestClient) -> None:
    body = fake_client.get("/descriptors").json()
    assert body["default"] == "posture"
    assert [(d["name"], d["dimension"], d["version"]) for d in body["descriptors"]] == [
        ("posture", 3, 1),
        ("kinetic", 2, 1),
    ]
    health = fake_client.get("/health").json()
    assert health["status"] == "ok" and health["clips"] == 0
    assert health["indexes"]["posture"] == {"size": 0, "dimension": 3, "version": 1, "missing": 0}


# -- issue 24: similarity, collapse=capture, "this file is clip #N" ------------------------


def add(client: TestClient, name: str, posture: list[float], kinetic: list[float]) -> int:
    # The name goes into the bytes too: same vectors, another file.
    motion = fake_motion(posture, kinetic, name=name)
    response = client.post("/clips", files={"file": (f"{name}.bvh", motion)})
    assert response.status_code == 201, response.text
    clip_id: int = response.json()["id"]
    return clip_id


def test_every_hit_has_a_similarity_that_falls_with_distance(fake_client: TestClient) -> None:
    ids = library(fake_client)
    for clip in ids[:3]:
        hits = fake_client.get("/search", params={"clip": clip, "k": 10}).json()["results"]
        similarity = [h["similarity"] for h in hits]
        assert all(0.0 <= s <= 100.0 for s in similarity)
        assert similarity == sorted(similarity, reverse=True)
        assert similarity[0] > similarity[-1]
    same = fake_client.post("/search", files={"file": ("c.bvh", fake_motion([0, 0, 0]))})
    assert same.json()["results"][0]["similarity"] == 100.0  # nothing is nearer than 0


def test_collapse_capture_keeps_one_result_per_capture(fake_client: TestClient) -> None:
    query = add(fake_client, "q", [0, 0, 0], [0, 0])
    copy = add(fake_client, "q_copy", [0, 0, 0], [0, 0])
    a = add(fake_client, "a", [1, 0, 0], [1, 1])
    a_bvh = add(fake_client, "a_bvh", [1, 0, 0], [1, 1])
    a_amc = add(fake_client, "a_amc", [1, 0, 0], [1, 1])
    b = add(fake_client, "b", [2, 0, 0], [5, 5])
    c = add(fake_client, "c", [3, 0, 0], [5, 5])  # as near as b under kinetic only
    plain = fake_client.get(f"/search?clip={query}&k=3").json()
    assert [h["id"] for h in plain["results"]] == [copy, a, a_bvh]
    assert "others" not in plain["results"][0] and "query_others" not in plain
    body = fake_client.get(f"/search?clip={query}&k=3&collapse=capture").json()
    assert [h["id"] for h in body["results"]] == [a, b, c]
    assert [o["id"] for o in body["results"][0]["others"]] == [a_bvh, a_amc]
    assert body["results"][0]["others"][0]["distance"] == 1.0
    assert body["results"][1]["others"] == []
    assert [o["id"] for o in body["query_others"]] == [copy]
    # A file: its own capture is a result like any other.
    uploaded = fake_client.post(
        "/search?k=2&collapse=capture", files={"file": ("x.bvh", fake_motion([0, 0, 0], [0, 0]))}
    ).json()
    assert [h["id"] for h in uploaded["results"]] == [query, a]
    assert [o["id"] for o in uploaded["results"][0]["others"]] == [copy]
    bad = fake_client.get(f"/search?clip={query}&collapse=files")
    assert bad.status_code == 422 and bad.json()["error"] == "invalid_input"


def test_searching_with_a_stored_file_says_which_clip_it_is(fake_client: TestClient) -> None:
    ids = library(fake_client)
    stored = fake_client.get(f"/clips/{ids[2]}").json()
    data = fake_motion(POINTS[2], kinetic=[2, 0])  # the very bytes library() uploaded as c2
    body = fake_client.post("/search?k=1", files={"file": ("any name.bvh", data)}).json()
    assert body["query"]["stored_clip"] == {"id": ids[2], "name": stored["name"]}
    assert body["results"][0]["id"] == ids[2] and body["results"][0]["distance"] == 0.0
    other = fake_client.post("/search?k=1", files={"file": ("n.bvh", fake_motion([9, 9, 9]))})
    assert other.json()["query"]["stored_clip"] is None


def test_a_plain_query_answers_as_fastapi_reads_it(fake_client: TestClient) -> None:
    """``GET /search`` reads ``clip``/``k``/``descriptor`` written plainly itself (issue 23,
    app/api/search.py) and leaves any other query to FastAPI: the same query written both
    ways gets the same status and the same bytes, answers and errors alike."""
    ids = library(fake_client)
    missing = max(ids) + 1000
    same = [
        (f"clip={ids[0]}&k=3", f"k=03&clip=0{ids[0]}"),
        (f"clip={ids[2]}&descriptor=kinetic", f"descriptor=kinetic&clip={ids[2]}&label="),
        (f"clip={ids[1]}", f"clip=%2B{ids[1]}"),
        (f"clip={missing}&k=2", f"clip=0{missing}&k=2"),  # 404
        (f"clip={ids[0]}&k=100000", f"clip={ids[0]}&k=0100000"),  # 422: k above the most
        (f"clip={ids[0]}&descriptor=nope", f"clip={ids[0]}&descriptor=%6Eope"),  # 422
    ]
    for plain, other in same:
        first, second = fake_client.get(f"/search?{plain}"), fake_client.get(f"/search?{other}")
        assert first.status_code == second.status_code, (plain, first.text, second.text)
        assert first.content == second.content, (plain, other)
    # What only FastAPI reads still answers as before: a missing clip, a bad number, an
    # unknown parameter, a repeated clip (the last one counts).
    assert fake_client.get("/search?k=3").status_code == 422
    assert fake_client.get("/search?clip=x").json()["error"] == "invalid_input"
    assert fake_client.get(f"/search?clip={ids[0]}&kk=3").status_code == 422
    repeated = fake_client.get(f"/search?clip={ids[0]}&clip={ids[1]}").json()
    assert repeated["query"]["id"] == ids[1]
