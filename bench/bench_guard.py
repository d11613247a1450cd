"""What the request guard (``app/api/guard.py``: Host, Origin, key, per-client slots, checked
on every request's head) costs on the hottest route, ``GET /search?clip=``.

Run from the repository root::

    .venv/bin/python bench/bench_guard.py [--requests 20000]

Builds the real app twice on one small library (the real motion core, three real clips), once
as served and once with the guard taken out of its middleware, and calls each as an ASGI
application directly (no network, no client: only the app's own work) for ``--requests``
searches, in rounds, alternating which goes first; then the guard alone around an app that does
nothing (its own cost, free of the search's noise). Prints the medians, the ratio and the
load average (the machine is shared).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from common import ROOT, machine

sys.path.insert(0, str(ROOT))

from fastapi.testclient import TestClient  # (after the path is set)

from app.api.guard import AccessTable, RequestGuard
from app.config import Settings
from app.main import create_app
from tests.hardening.live import unique_upload


def without_guard(app: Any) -> Any:
    app.user_middleware = [m for m in app.user_middleware if m.cls is not RequestGuard]
    app.middleware_stack = None
    return app


async def call(app: Any, path: str, query: bytes) -> int:
    status = 0

    async def receive() -> dict[str, Any]:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: dict[str, Any]) -> None:
        nonlocal status
        if message["type"] == "http.response.start":
            status = message["status"]

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "GET",
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "query_string": query,
        "headers": [(b"host", b"127.0.0.1:8000")],
        "client": ("127.0.0.1", 50000),
        "server": ("127.0.0.1", 8000),
        "state": {},
    }
    await app(scope, receive, send)
    return status


async def nothing(scope: Any, receive: Any, send: Any) -> None:
    await send({"type": "http.response.start", "status": 200, "headers": []})
    await send({"type": "http.response.body", "body": b""})


async def per_request(app: Any, count: int) -> float:
    started = time.perf_counter()
    for n in range(count):
        status = await call(app, "/search", b"clip=%d&k=2" % (1 + n % 3))
        assert status == 200, status
    return (time.perf_counter() - started) / count


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    print(f"machine: {machine()}")
    work = Path(tempfile.mkdtemp(prefix="bench-guard-"))
    try:
        return measure(args, Settings(data_dir=work / "data"))
    finally:
        shutil.rmtree(work, ignore_errors=True)


def measure(args: argparse.Namespace, settings: Settings) -> int:
    with TestClient(create_app(settings), base_url="http://127.0.0.1") as client:
        for n in range(3):
            assert client.post("/clips", files=unique_upload(n)).status_code == 201
    guarded, bare = create_app(settings), without_guard(create_app(settings))
    times: dict[str, list[float]] = {"with the guard": [], "without": []}
    with TestClient(guarded), TestClient(bare):  # lifespans: libraries opened
        order = [("with the guard", guarded), ("without", bare)]
        for _ in range(args.rounds):
            order.reverse()  # alternate which goes first
            for name, app in order:
                count = args.requests // args.rounds
                times[name].append(asyncio.run(per_request(app, count)))
        alone = RequestGuard(
            nothing, settings=settings, access_table=lambda: AccessTable.of(guarded.openapi())
        )
        for _ in range(args.rounds):
            times.setdefault("guard alone", []).append(
                asyncio.run(per_request(alone, args.requests))
            )
            times.setdefault("no-op app", []).append(
                asyncio.run(per_request(nothing, args.requests))
            )
    medians = {name: statistics.median(values) for name, values in times.items()}
    for name, value in medians.items():
        print(f"GET /search?clip=&k=2, {name:15}: {value * 1e6:8.1f} µs per request")
    whole = medians["with the guard"] / medians["without"]
    own = medians["guard alone"] - medians["no-op app"]
    print(
        f"whole app with / without the guard: {whole:.3f}; the guard's own work: {own * 1e6:.1f} µs"
    )
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
