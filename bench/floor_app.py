"""The HTTP floor: the least a FastAPI search route can cost on this machine.

One ``GET`` route taking the same query as ``GET /search`` and ``GET /search/moments``
(``clip``, ``k``, ``descriptor``, validated by FastAPI) and answering ten hits' worth of JSON
built once at start-up. ``bench/bench_search.py`` and ``bench/bench_moments.py`` serve it with
the same uvicorn, the same worker count and the same ``wrk`` settings as the service, in the
same run, and print the service's requests/s as a share of the floor's: on a shared 2-core
machine a ratio measured side by side is what survives the noise.

Served as ``uvicorn floor_app:create_floor_app --factory`` from ``bench/``.
"""

from __future__ import annotations

import json

from fastapi import FastAPI, Query, Response

HIT = {
    "id": 123456,
    "name": "dataset-1_walk_happy_001",
    "labels": ["walk", "happy"],
    "format": "bvh",
    "filenames": ["dataset-1_walk_happy_001.bvh"],
    "skeleton_family": "bandai",
    "distance": 1.2345678901234567,
}


def floor_body() -> bytes:
    """A search answer's shape: the query, then ten hits (what ``bench/search.lua`` checks)."""
    body = {
        "query": {"id": 1, "name": "dataset-1_walk_happy_001"},
        "descriptor": "motion",
        "k": 10,
        "results": [HIT] * 10,
    }
    return json.dumps(body, separators=(",", ":")).encode()


def create_floor_app() -> FastAPI:
    app = FastAPI(title="HTTP floor")
    body = floor_body()

    @app.get("/search")
    @app.get("/search/moments")
    async def search(clip: int = Query(), k: int = 10, descriptor: str | None = None) -> Response:
        return Response(body, media_type="application/json")

    @app.get("/health")
    async def health() -> Response:
        return Response(b'{"status":"ok"}', media_type="application/json")

    return app
