"""A crowd of uploads at once, on a real server: the describes are bounded, the rest of the
crowd is told to come back (503 ``busy`` with Retry-After), ``/health`` keeps answering
within a second, and the library stays consistent.

Scaled for CI (``MOCAP_MAX_FRAME_VALUES`` a tenth of its default, so "at the cap" is a tenth
of the size); ``bench/bench_busy.py`` runs the same crowd at the real limits and measures the
server's memory against the documented bound.
"""

from __future__ import annotations

import multiprocessing
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from tests.hardening.live import (
    LiveServer,
    all_clips,
    database_problems,
    service_problems,
    stretched_bvh,
)

FRAME_VALUES = 2_000_000
LARGE = 40  # uploads of a long take
AT_THE_CAP = 12  # uploads just under MOCAP_MAX_FRAME_VALUES
HEALTH_LIMIT = 1.0  # seconds


def frames_at_the_cap() -> int:
    """Frames of the fixture's skeleton just under FRAME_VALUES (9 values per joint and frame,
    38 joints with the end sites)."""
    return FRAME_VALUES // (9 * 38) - 10


@dataclass
class Crowd:
    lock: threading.Lock = field(default_factory=threading.Lock)
    answers: list[tuple[str, int, dict[str, str], str]] = field(default_factory=list)
    health: list[float] = field(default_factory=list)
    health_failures: list[str] = field(default_factory=list)


def upload(url: str, name: str, data: bytes, crowd: Crowd, start: threading.Barrier) -> None:
    start.wait(60)
    with httpx.Client(base_url=url, timeout=120) as client:
        try:
            response = client.post("/clips", files={"file": (name, data)})
        except httpx.HTTPError as error:
            with crowd.lock:
                crowd.answers.append((name, 0, {}, repr(error)))
            return
    with crowd.lock:
        crowd.answers.append((name, response.status_code, dict(response.headers), response.text))


def watch_health(url: str, stop: Any, results: Any) -> None:
    """Ask ``/health`` every 50 ms until ``stop`` is set; send back (latencies, failures).

    Runs in a process of its own, so the uploading threads of the test do not slow the
    watcher down (the latency is the server's, not this process's)."""
    latencies: list[float] = []
    failures: list[str] = []
    with httpx.Client(base_url=url, timeout=30) as client:
        while not stop.is_set():
            started = time.monotonic()
            try:
                status = client.get("/health").status_code
            except httpx.HTTPError as error:
                failures.append(repr(error))
                continue
            latencies.append(time.monotonic() - started)
            if status != 200:
                failures.append(f"/health answered {status}")
            time.sleep(0.05)
    results.send((latencies, failures))


@contextmanager
def health_watched(url: str, crowd: Crowd) -> Iterator[None]:
    """``/health`` asked every 50 ms from another process meanwhile; latencies into ``crowd``."""
    context = multiprocessing.get_context("spawn")
    stop = context.Event()
    ours, theirs = context.Pipe()
    watcher = context.Process(target=watch_health, args=(url, stop, theirs))
    watcher.start()
    try:
        yield
    finally:
        stop.set()
        if ours.poll(60):
            crowd.health, crowd.health_failures = ours.recv()
        watcher.join(30)


def test_a_crowd_of_large_uploads(tmp_path: Path) -> None:
    env = {
        "MOCAP_MAX_CONCURRENT_DESCRIBES": "2",
        "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64",  # one address, many uploads at once
        "MOCAP_DESCRIBE_WAIT_SECONDS": "2",
        "MOCAP_MAX_FRAME_VALUES": str(FRAME_VALUES),
        "MOCAP_ORPHAN_FILE_GRACE_SECONDS": "0",
    }
    files = [(f"take_{n}.bvh", stretched_bvh(2000, n)) for n in range(LARGE)]
    files += [(f"cap_{n}.bvh", stretched_bvh(frames_at_the_cap(), 1000 + n)) for n in range(12)]
    crowd = Crowd()
    data_dir = tmp_path / "data"
    with LiveServer(data_dir, env) as server:
        with health_watched(server.url, crowd):
            time.sleep(0.5)  # the watcher is asking before the crowd comes
            start = threading.Barrier(len(files))
            uploaders = [
                threading.Thread(target=upload, args=(server.url, name, data, crowd, start))
                for name, data in files
            ]
            for thread in uploaders:
                thread.start()
            for thread in uploaders:
                thread.join(300)
                assert not thread.is_alive(), "an upload hung"
        with httpx.Client(base_url=server.url, timeout=60) as client:
            clips = all_clips(client)
            problems = service_problems(client)
        log = server.log()
    problems += database_problems(data_dir, 3)

    statuses = [status for _, status, _, _ in crowd.answers]
    print(
        f"\ncrowd: {sorted(statuses).count(201)} x 201, {statuses.count(503)} x 503; /health "
        f"{len(crowd.health)} times, slowest {max(crowd.health, default=0):.3f} s"
    )
    assert len(statuses) == len(files)
    assert set(statuses) <= {200, 201, 503}, [a for a in crowd.answers if a[1] not in (201, 503)]
    busy = [answer for answer in crowd.answers if answer[1] == 503]
    assert busy, "the crowd was never turned away: the describes are not bounded"
    for _, _, headers, text in busy:
        assert '"error":"busy"' in text and "MOCAP_MAX_CONCURRENT_DESCRIBES" in text, text
        assert int(headers["retry-after"]) >= 1
    stored = {name for name, status, _, _ in crowd.answers if status == 201}
    assert stored and {clip["name"] + ".bvh" for clip in clips.values()} == stored
    assert not crowd.health_failures, crowd.health_failures[:5]
    assert len(crowd.health) > 10 and max(crowd.health) < HEALTH_LIMIT, sorted(crowd.health)[-5:]
    assert not problems, problems
    assert "Traceback" not in log, log[-3000:]


def test_the_gate_knows_every_route_that_reads_an_upload(settings: Any) -> None:
    """DescribeGate turns uploads away by path: it must know each route taking a multipart
    upload (as the OpenAPI schema documents them)."""
    from app.api.limits import UPLOAD_ROUTES
    from app.main import create_app

    paths = create_app(settings).openapi()["paths"]
    uploads = {
        (path, method.upper())
        for path, operations in paths.items()
        for method, operation in operations.items()
        if "multipart/form-data" in operation.get("requestBody", {}).get("content", {})
    }
    assert uploads == {(path, "POST") for path in UPLOAD_ROUTES}
