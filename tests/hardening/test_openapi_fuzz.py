"""Schemathesis against the live server: requests generated from the OpenAPI schema (valid and
invalid) never get a 5xx, and every response matches what the schema documents (status code,
content type, headers, body).

The server runs with an API key and a few real clips, so both the refusals (401/403) and the
answers about stored clips are exercised. Examples per operation: ``MOCAP_FUZZ_EXAMPLES``
(default 25; docs/hardening.md records a longer run). CI draws the same examples every time
(hypothesis ``derandomize``); ``MOCAP_FUZZ_RANDOM=1`` draws new ones.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import checks
from schemathesis.generation import GenerationMode

from tests.hardening.live import LiveServer, unique_upload

EXAMPLES = int(os.environ.get("MOCAP_FUZZ_EXAMPLES", "25"))
RANDOM = os.environ.get("MOCAP_FUZZ_RANDOM") == "1"
KEY = "fuzz-key-4f7a"
CHECKS = [
    checks.not_a_server_error,
    checks.status_code_conformance,
    checks.content_type_conformance,
    checks.response_headers_conformance,
    checks.response_schema_conformance,
]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    data_dir = tmp_path_factory.mktemp("fuzz") / "data"
    with LiveServer(data_dir, {"MOCAP_API_KEY": KEY}) as live:
        with httpx.Client(base_url=live.url, headers={"X-API-Key": KEY}, timeout=30) as client:
            for n in range(4):
                assert client.post("/clips", files=unique_upload(n)).status_code == 201
        yield live
    assert KEY not in live.log(), "the API key appeared in the server log"
    assert "Traceback" not in live.log(), live.log()[-3000:]


def operations(server: LiveServer) -> list[Any]:
    schema = schemathesis.openapi.from_url(f"{server.url}/openapi.json")
    found = [result.ok() for result in schema.get_all_operations()]
    assert {op.label for op in found} >= {
        "POST /clips",
        "GET /clips",
        "GET /clips/{clip_id}",
        "GET /clips/{clip_id}/file",
        "PATCH /clips/{clip_id}",
        "DELETE /clips/{clip_id}",
        "GET /search",
        "POST /search",
        "GET /descriptors",
        "GET /health",
    }
    return found


def run_operation(server: LiveServer, operation: Any, mode: GenerationMode, auth: bool) -> None:
    headers = {"X-API-Key": KEY} if auth else {}

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        database=None,
        derandomize=not RANDOM,
        suppress_health_check=list(HealthCheck),
    )
    @given(case=operation.as_strategy(generation_mode=mode))
    def check(case: Any) -> None:
        response = case.call(base_url=server.url, headers=headers, timeout=30)
        case.validate_response(response, checks=CHECKS)

    try:
        check()
    except Unsatisfiable:
        # nothing in the schema can be made invalid (e.g. GET /health takes no input)
        assert mode == GenerationMode.NEGATIVE, operation.label


@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE])
def test_generated_requests_with_the_key(server: LiveServer, mode: GenerationMode) -> None:
    for operation in operations(server):
        run_operation(server, operation, mode, auth=True)
    assert httpx.get(f"{server.url}/health", timeout=10).status_code == 200


def test_generated_requests_without_a_key(server: LiveServer) -> None:
    with httpx.Client(base_url=server.url, headers={"X-API-Key": KEY}, timeout=30) as client:
        for n in range(4, 8):  # clips that generated deletes may hit (ids are small numbers)
            assert client.post("/clips", files=unique_upload(n)).status_code in (200, 201)
        before = client.get("/clips", params={"limit": 500}).json()
    for operation in operations(server):
        run_operation(server, operation, GenerationMode.POSITIVE, auth=False)
    # nothing changed without the key
    assert httpx.get(f"{server.url}/clips", params={"limit": 500}, timeout=10).json() == before
