"""Load: 8 concurrent uploaders (now and then all 8 with identical content at the same moment)
and 16 concurrent searchers against the real server on loopback.

No 5xx; identical content becomes one clip (one 201, seven 200 with the same id); every
acknowledged clip is there afterwards; every id a search returned can be loaded. Throughput and
latency percentiles are printed (``pytest -s``) and written to ``$MOCAP_LOAD_REPORT`` when set.

Duration: ``MOCAP_LOAD_SECONDS`` (10 s by default, for CI; docs/hardening.md records 60 s).
"""

from __future__ import annotations

import json
import os
import random
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from tests.hardening.live import (
    LiveServer,
    all_clips,
    database_problems,
    percentiles,
    service_problems,
    unique_upload,
)

SECONDS = float(os.environ.get("MOCAP_LOAD_SECONDS", "10"))
UPLOADERS = 8
SEARCHERS = 16
SAME_CONTENT_EVERY = 4  # every 4th upload of each uploader is a shared one, sent together


@dataclass
class Record:
    lock: threading.Lock = field(default_factory=threading.Lock)
    latencies: dict[str, list[float]] = field(default_factory=lambda: defaultdict(list))
    statuses: dict[str, dict[int, int]] = field(
        default_factory=lambda: defaultdict(lambda: defaultdict(int))
    )
    errors: list[str] = field(default_factory=list)
    acknowledged: dict[str, int] = field(default_factory=dict)  # content hash -> clip id
    shared: dict[int, set[int]] = field(default_factory=lambda: defaultdict(set))  # n -> ids
    shared_created: dict[int, int] = field(default_factory=lambda: defaultdict(int))
    seen_in_results: set[int] = field(default_factory=set)
    ids: list[int] = field(default_factory=list)

    def note(self, kind: str, started: float, response: httpx.Response) -> None:
        elapsed = time.monotonic() - started
        with self.lock:
            self.latencies[kind].append(elapsed)
            self.statuses[kind][response.status_code] += 1
            if response.status_code >= 500:
                self.errors.append(f"{kind}: {response.status_code} {response.text[:200]}")


def uploader(
    url: str, me: int, record: Record, stop: threading.Event, barrier: threading.Barrier
) -> None:
    counter = 0
    with httpx.Client(base_url=url, timeout=60) as client:
        while not stop.is_set():
            counter += 1
            # the first upload of each is shared, so a round runs however loaded the machine
            shared = counter % SAME_CONTENT_EVERY == 1
            if shared:
                number = 1_000_000 + counter  # the same for every uploader this time
                try:
                    barrier.wait(timeout=30)  # all 8 send it at the same moment
                except threading.BrokenBarrierError:
                    return
            else:
                number = 10_000 * (me + 1) + counter
            started = time.monotonic()
            try:
                response = client.post("/clips", files=unique_upload(number))
            except httpx.HTTPError as exc:
                record.errors.append(f"upload: {exc!r}")
                continue
            record.note("upload", started, response)
            if response.status_code not in (200, 201):
                record.errors.append(f"upload: {response.status_code} {response.text[:200]}")
                continue
            clip = response.json()
            with record.lock:
                known = record.acknowledged.setdefault(clip["content_hash"], clip["id"])
                if known != clip["id"]:
                    record.errors.append(f"same content, two ids: {known} and {clip['id']}")
                record.ids.append(clip["id"])
                if shared:
                    record.shared[number].add(clip["id"])
                    record.shared_created[number] += response.status_code == 201


def searcher(url: str, record: Record, stop: threading.Event, rng: random.Random) -> None:
    descriptors = ["posture", "kinetic", "motion"]
    with httpx.Client(base_url=url, timeout=60) as client:
        while not stop.is_set():
            with record.lock:
                ids = list(record.ids[-200:])
            by_upload = rng.random() < 0.1 or not ids
            started = time.monotonic()
            try:
                if by_upload:
                    response = client.post(
                        "/search",
                        params={"k": 10, "descriptor": rng.choice(descriptors)},
                        files=unique_upload(rng.randrange(10**6)),
                    )
                    kind = "search by upload"
                else:
                    name = rng.choice(descriptors)
                    query = {"clip": rng.choice(ids), "k": 10, "descriptor": name}
                    response = client.get("/search", params=query)
                    kind = "search by clip"
            except httpx.HTTPError as exc:
                record.errors.append(f"search: {exc!r}")
                continue
            record.note(kind, started, response)
            if response.status_code != 200:
                record.errors.append(f"{kind}: {response.status_code} {response.text[:200]}")
                continue
            with record.lock:
                record.seen_in_results.update(hit["id"] for hit in response.json()["results"])


def test_concurrent_uploads_and_searches(tmp_path: Path) -> None:
    record = Record()
    data_dir = tmp_path / "data"
    # Every client of this test shares the loopback address: the per-client bound on heavy
    # requests (tests/hardening/test_access.py) would make them one client.
    env = {"MOCAP_MAX_K": "100000", "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64"}
    with LiveServer(data_dir, env) as server:
        stop = threading.Event()
        barrier = threading.Barrier(UPLOADERS)
        rng = random.Random(6)
        threads = [
            threading.Thread(target=uploader, args=(server.url, i, record, stop, barrier))
            for i in range(UPLOADERS)
        ]
        for _ in range(SEARCHERS):
            own_rng = random.Random(rng.random())
            args = (server.url, record, stop, own_rng)
            threads.append(threading.Thread(target=searcher, args=args))
        started = time.monotonic()
        for thread in threads:
            thread.start()
        time.sleep(SECONDS)
        stop.set()
        barrier.abort()
        for thread in threads:
            thread.join(timeout=120)
            assert not thread.is_alive(), "a client thread hung"
        elapsed = time.monotonic() - started

        with httpx.Client(base_url=server.url, timeout=60) as client:
            clips = all_clips(client)
            problems = service_problems(client)
        log = server.log()
    problems += database_problems(data_dir, 3)

    summary = {
        "seconds": round(elapsed, 1),
        "uploaders": UPLOADERS,
        "searchers": SEARCHERS,
        "clips": len(clips),
        "operations": {
            kind: {
                "count": len(values),
                "per_second": round(len(values) / elapsed, 1),
                "statuses": dict(record.statuses[kind]),
                **percentiles(values),
            }
            for kind, values in sorted(record.latencies.items())
        },
    }
    print("\nload test:", json.dumps(summary, indent=2))
    if os.environ.get("MOCAP_LOAD_REPORT"):
        Path(os.environ["MOCAP_LOAD_REPORT"]).write_text(json.dumps(summary, indent=2) + "\n")

    assert not record.errors, record.errors[:10]
    assert not problems, problems
    assert record.latencies["upload"] and record.latencies["search by clip"]
    # identical content at the same moment: one clip, created once, the same id for all
    assert record.shared, "no round of identical uploads ran"
    for number, ids in record.shared.items():
        assert len(ids) == 1, (number, ids)
        assert record.shared_created[number] <= 1, number
    # every acknowledged clip is there, once; every id a search returned can be loaded
    assert set(record.acknowledged.values()) == set(clips)
    assert record.seen_in_results <= set(clips)
    assert "Traceback" not in log, log[-3000:]
