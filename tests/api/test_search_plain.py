"""A plain ``GET /search`` is answered before FastAPI's routing (``PlainSearches``,
app/api/search.py; issue 23): the same status, headers and bytes as FastAPI's route gives,
and every other request — errors included — still FastAPI's."""

from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from opentelemetry import _logs, metrics, trace
from starlette.types import ASGIApp, Receive, Scope, Send

from app.api.search import CORES, LANE
from app.api.search_lane import PROBE_EVERY
from app.config import Settings
from app.main import create_app, telemetry_signals
from tests.api.test_search import library
from tests.conftest import new_sqlite_settings
from tests.services.fakes import FakeDescriber, fake_motion


class Routed:
    """The app, remembering whether FastAPI's router answered each request (it puts the
    route's endpoint in the request's scope)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.scopes: list[dict[str, Any]] = []

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http":
            self.scopes.append(scope)
        await self.app(scope, receive, send)

    def last_by_router(self) -> bool:
        return "endpoint" in self.scopes[-1]


def client_of(settings: Settings) -> tuple[TestClient, Routed]:
    routed = Routed(create_app(settings, describer=FakeDescriber()))
    return TestClient(routed), routed


@pytest.fixture
def served(tmp_path: Path, migrated_sqlite_file: Path) -> Iterator[tuple[TestClient, Routed]]:
    client, routed = client_of(new_sqlite_settings(tmp_path / "data", migrated_sqlite_file))
    with client:
        yield client, routed


def test_a_plain_search_answers_as_the_route_does(served: tuple[TestClient, Routed]) -> None:
    client, routed = served
    ids = library(client)
    # The same query, written plainly and (leading zeros) for FastAPI to read.
    for plain, routed_query in [
        (f"clip={ids[0]}&k=3", f"clip=0{ids[0]}&k=3"),
        (f"clip={ids[2]}&descriptor=kinetic", f"clip=0{ids[2]}&descriptor=kinetic"),
        (f"k=10&clip={ids[5]}", f"k=010&clip={ids[5]}"),
    ]:
        first = client.get(f"/search?{plain}")
        assert not routed.last_by_router(), plain
        second = client.get(f"/search?{routed_query}")
        assert routed.last_by_router(), routed_query
        assert first.status_code == second.status_code == 200
        assert first.headers.items() == second.headers.items()
        assert first.content == second.content
    # Larger answers are compressed for a client that asks, by the same layer.
    many = {"Accept-Encoding": "gzip"}
    first = client.get(f"/search?clip={ids[0]}&k=5", headers=many)
    second = client.get(f"/search?clip=0{ids[0]}&k=5", headers=many)
    assert first.headers.items() == second.headers.items()
    assert first.content == second.content


def test_errors_and_other_queries_are_fastapis(served: tuple[TestClient, Routed]) -> None:
    client, routed = served
    ids = library(client)
    # A plain query whose search fails is answered by the route: FastAPI's error, its bytes.
    for query, status in [
        (f"clip={max(ids) + 1000}", 404),
        (f"clip={ids[0]}&k=100000", 422),
        (f"clip={ids[0]}&descriptor=nope", 422),
    ]:
        response = client.get(f"/search?{query}")
        assert response.status_code == status and routed.last_by_router(), query
        assert set(response.json()) == {"error", "detail"}
    for other in [f"clip={ids[0]}&label=even", f"clip={ids[0]}&kk=3", "k=3", "clip=x"]:
        client.get(f"/search?{other}")
        assert routed.last_by_router(), other
    # HEAD runs as the GET it stands for (app/api/head.py): its status and headers, no body.
    head, get = client.head(f"/search?clip={ids[0]}"), client.get(f"/search?clip={ids[0]}")
    assert (head.status_code, head.content) == (200, b"")
    assert head.headers["content-length"] == get.headers["content-length"]
    assert client.get(f"/search/?clip={ids[0]}", follow_redirects=False).status_code == 307


def test_reads_needing_a_key_go_through_the_route(
    tmp_path: Path, migrated_sqlite_file: Path
) -> None:
    settings = new_sqlite_settings(tmp_path / "data", migrated_sqlite_file)
    settings = settings.model_copy(update={"api_key": "k3y-one", "require_key_for_reads": True})
    client, routed = client_of(settings)
    with client:
        key = {"X-API-Key": "k3y-one"}
        ids = [
            client.post("/clips", files={"file": (f"c{i}.bvh", fake(i))}, headers=key).json()["id"]
            for i in range(3)
        ]
        assert client.get(f"/search?clip={ids[0]}").status_code == 401
        answer = client.get(f"/search?clip={ids[0]}&k=2", headers=key)
        assert answer.status_code == 200 and routed.last_by_router()


def fake(number: int) -> bytes:
    return fake_motion([number, 0, 0], kinetic=[number, 0])


def test_a_search_asks_opentelemetry_nothing_when_it_is_not_set_up(
    served: tuple[TestClient, Routed], monkeypatch: pytest.MonkeyPatch
) -> None:
    # FastAPI's own telemetry asked the three global providers at every request (reading an
    # environment variable each while none is set): decided once when the app was created.
    client, _ = served
    ids = library(client)

    def asked() -> None:
        raise AssertionError("a request asked for an OpenTelemetry provider")

    for name in ("get_tracer_provider", "get_meter_provider", "get_logger_provider"):
        module = {"get_tracer_provider": trace, "get_meter_provider": metrics}.get(name, _logs)
        monkeypatch.setattr(module, name, asked)
    assert client.get(f"/search?clip={ids[0]}&k=3").status_code == 200
    assert client.get(f"/search?clip=0{ids[0]}&k=3").status_code == 200  # FastAPI's route


def test_telemetry_signals_follow_the_providers_configured_at_creation(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv("FASTAPI_OTEL_AUTO_CONFIGURE", raising=False)
    unset = (trace.get_tracer_provider(), metrics.get_meter_provider(), _logs.get_logger_provider())
    assert telemetry_signals(*unset) == {"tracing": False, "metrics": False, "logs": False}
    # A provider someone set (here the API's no-op one; an SDK's in a deployment)
    tracer = trace.NoOpTracerProvider()
    assert telemetry_signals(tracer, *unset[1:]) == {
        "tracing": True,
        "metrics": False,
        "logs": False,
    }
    monkeypatch.setenv("FASTAPI_OTEL_AUTO_CONFIGURE", "true")  # FastAPI sets them up at start
    assert telemetry_signals(*unset) == {}


def test_searches_at_once_have_their_scans_batched_and_answer_as_alone(
    served: tuple[TestClient, Routed],
) -> None:
    """Plain searches in flight together hand their index scans to the search lane
    (app/api/search_lane.py), which scans those waiting in one FAISS call: every answer
    is the bytes the same search gives alone."""
    client, _ = served
    ids = library(client)
    queries = [f"/search?clip={i}&k={k}" for i in ids for k in (1, 3, 10)]
    queries += [f"/search?clip={i}&descriptor=kinetic" for i in ids]
    before = LANE.scanned
    alone = {query: client.get(query) for query in queries * 2}  # and the kinds measured quick
    # one after another, each runs inline but for the lane's probe now and then
    assert LANE.scanned - before <= len(queries * 2) // PROBE_EVERY + 1
    before = LANE.scanned
    with ThreadPoolExecutor(16) as pool:  # the client's requests share its event loop
        together = list(pool.map(client.get, queries * 8))
    assert LANE.scanned > before or CORES == 1  # no core to spare: inline
    for query, response in zip(queries * 8, together, strict=True):
        assert response.status_code == 200
        assert response.content == alone[query].content, query
    # a search of a missing clip among them is still FastAPI's 404
    with ThreadPoolExecutor(8) as pool:
        mixed = list(pool.map(client.get, [f"/search?clip={max(ids) + 50}", *queries[:20]]))
    assert mixed[0].status_code == 404 and all(r.status_code == 200 for r in mixed[1:])


def test_with_a_server_process_per_core_searches_stay_inline(
    tmp_path: Path, migrated_sqlite_file: Path
) -> None:
    settings = new_sqlite_settings(tmp_path / "data", migrated_sqlite_file)
    client, _ = client_of(settings.model_copy(update={"workers": CORES}))
    with client:
        ids = library(client)
        queries = [f"/search?clip={i}&k=3" for i in ids] * 8
        before = LANE.scanned
        with ThreadPoolExecutor(16) as pool:
            answers = list(pool.map(client.get, queries))
        assert all(answer.status_code == 200 for answer in answers)
        assert LANE.scanned == before
