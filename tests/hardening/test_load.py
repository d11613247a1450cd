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
from collections.abc import Iterator
from contextlib import contextmanager
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
        """Count the answer; a 5xx is an error, but for 503 ``busy`` (too many describes at
        once: the client is told to come back, as it should be under load)."""
        elapsed = time.monotonic() - started
        with self.lock:
            self.latencies[kind].append(elapsed)
            self.statuses[kind][response.status_code] += 1
            if response.status_code >= 500 and not busy(response):
                self.errors.append(f"{kind}: {response.status_code} {response.text[:200]}")

    def operations(self, elapsed: float) -> dict[str, dict[str, object]]:
        """Per kind of request: count, rate, statuses and latency percentiles (ms)."""
        return {
            kind: {
                "count": len(values),
                "per_second": round(len(values) / elapsed, 1),
                "statuses": dict(self.statuses[kind]),
                **percentiles(values),
            }
            for kind, values in sorted(self.latencies.items())
        }


def busy(response: httpx.Response) -> bool:
    """A 503 ``busy`` with Retry-After: the server turned the request away, on purpose."""
    return (
        response.status_code == 503
        and response.json().get("error") == "busy"
        and int(response.headers.get("retry-after", "0")) >= 1
    )


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
            if busy(response):
                continue
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
            if busy(response):
                continue
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
        "operations": record.operations(elapsed),
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


# -- the crowd: every operation at once, on one server and on two replicas -------------------

# Read at import: the tests' fixture clears MOCAP_* variables before each test.
CROWD_SECONDS = float(os.environ.get("MOCAP_CROWD_SECONDS", "12"))
CROWD_REPORT = os.environ.get("MOCAP_CROWD_REPORT")
CROWD_CLIENTS = 8
# operation -> weight (out of 100)
CROWD_MIX = {
    "upload": 30,
    "delete": 8,
    "relabel": 12,
    "search by clip": 22,
    "search by upload": 5,
    "moments by clip": 15,
    "moments by upload": 8,
}


@dataclass
class CrowdLedger:
    """What the crowd was told: every acknowledged upload, delete and relabel."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    record: Record = field(default_factory=Record)
    stored: dict[int, str] = field(default_factory=dict)  # clip id -> content hash
    deleted: set[int] = field(default_factory=set)
    labels: dict[int, list[str]] = field(default_factory=dict)  # the last relabel answered
    busy: int = 0


def crowd_client(
    urls: list[str], me: int, ledger: CrowdLedger, stop: threading.Event, seed: int
) -> None:
    """One client of the crowd: a random operation at a time, on a random server; it deletes
    and relabels only its own clips (so the last answer it got is the truth)."""
    rng = random.Random(seed)
    mine: list[int] = []
    counter = 0
    operations, weights = zip(*CROWD_MIX.items(), strict=True)
    clients = [httpx.Client(base_url=url, timeout=120) for url in urls]
    try:
        while not stop.is_set():
            client = rng.choice(clients)
            kind = rng.choices(operations, weights)[0]
            with ledger.lock:
                known = [i for i in ledger.stored if i not in ledger.deleted]
            if kind in ("delete", "relabel") and not mine:
                kind = "upload"
            if kind in ("search by clip", "moments by clip") and not known:
                kind = "upload"
            started = time.monotonic()
            counter += 1
            try:
                response = crowd_request(client, kind, rng, me, counter, mine, known)
            except httpx.HTTPError as error:
                ledger.record.errors.append(f"{kind}: {error!r}")
                continue
            ledger.record.note(kind, started, response)
            crowd_answer(ledger, kind, response, mine)
    finally:
        for client in clients:
            client.close()


def crowd_request(
    client: httpx.Client,
    kind: str,
    rng: random.Random,
    me: int,
    counter: int,
    mine: list[int],
    known: list[int],
) -> httpx.Response:
    if kind == "upload":
        return client.post("/clips", files=unique_upload(100_000 * (me + 1) + counter))
    if kind == "delete":
        return client.delete(f"/clips/{mine.pop(rng.randrange(len(mine)))}")
    if kind == "relabel":
        clip = rng.choice(mine)
        labels = [f"crowd-{me}", f"take-{counter}"]
        return client.patch(f"/clips/{clip}", json={"labels": labels})
    if kind == "search by clip":
        query = {"clip": rng.choice(known), "k": 10, "descriptor": rng.choice(DESCRIPTORS)}
        return client.get("/search", params=query)
    if kind == "search by upload":
        return client.post("/search", params={"k": 10}, files=unique_upload(rng.randrange(10**6)))
    if kind == "moments by clip":
        return client.get("/search/moments", params={"clip": rng.choice(known), "k": 5})
    return client.post(
        "/search/moments", params={"k": 5}, files=unique_upload(rng.randrange(10**6))
    )


def crowd_answer(ledger: CrowdLedger, kind: str, response: httpx.Response, mine: list[int]) -> None:
    """Record what an answer acknowledges; anything unexpected is an error."""
    status = response.status_code
    if busy(response):
        with ledger.lock:
            ledger.busy += 1
        return
    # A clip another client deleted meanwhile is gone: 404 for a search from it is right.
    expected = {"upload": (200, 201), "delete": (204,), "relabel": (200,)}.get(kind, (200,))
    if kind in ("search by clip", "moments by clip") and status == 404:
        return
    if status not in expected:
        ledger.record.errors.append(f"{kind}: {status} {response.text[:200]}")
        return
    with ledger.lock:
        if kind == "upload":
            clip = response.json()
            ledger.stored[clip["id"]] = clip["content_hash"]
            mine.append(clip["id"])
        elif kind == "delete":
            ledger.deleted.add(int(response.request.url.path.rsplit("/", 1)[1]))
        elif kind == "relabel":
            clip = response.json()
            ledger.labels[clip["id"]] = clip["labels"]


DESCRIPTORS = ["posture", "kinetic", "motion"]


def run_crowd(urls: list[str], seconds: float, seed: int = 21) -> tuple[CrowdLedger, float]:
    """``CROWD_CLIENTS`` clients for ``seconds`` against the servers at ``urls``."""
    ledger = CrowdLedger()
    stop = threading.Event()
    threads = [
        threading.Thread(target=crowd_client, args=(urls, me, ledger, stop, seed * 100 + me))
        for me in range(CROWD_CLIENTS)
    ]
    started = time.monotonic()
    for thread in threads:
        thread.start()
    time.sleep(seconds)
    stop.set()
    for thread in threads:
        thread.join(timeout=180)
        assert not thread.is_alive(), "a crowd client hung"
    return ledger, time.monotonic() - started


def crowd_summary(ledger: CrowdLedger, elapsed: float, servers: int) -> dict[str, object]:
    record = ledger.record
    return {
        "seconds": round(elapsed, 1),
        "clients": CROWD_CLIENTS,
        "servers": servers,
        "acknowledged uploads": len(ledger.stored),
        "acknowledged deletes": len(ledger.deleted),
        "503 busy": ledger.busy,
        "operations": record.operations(elapsed),
    }


def crowd_problems(ledger: CrowdLedger, urls: list[str]) -> list[str]:
    """Through every server: the clips are exactly the acknowledged uploads not deleted, with
    their last labels, each searchable (k = all) and the indexes agree (``service_problems``)."""
    problems: list[str] = []
    alive = {i: h for i, h in ledger.stored.items() if i not in ledger.deleted}
    for url in urls:
        with httpx.Client(base_url=url, timeout=120) as client:
            deadline = time.monotonic() + 10  # a replica follows the others within a refresh
            while True:
                clips = all_clips(client)
                found = service_problems(client)
                if (set(clips) == set(alive) and not found) or time.monotonic() > deadline:
                    break
                time.sleep(0.2)
            problems += [f"{url}: {p}" for p in found]
            if set(clips) != set(alive):
                missing = sorted(set(alive) - set(clips))[:5]
                extra = sorted(set(clips) - set(alive))[:5]
                problems.append(f"{url}: acknowledged but missing {missing}, unexpected {extra}")
            for clip_id, clip in clips.items():
                if clip_id in alive and clip["content_hash"] != alive[clip_id]:
                    problems.append(f"{url}: clip {clip_id} has another content")
                if clip_id in ledger.labels and clip["labels"] != ledger.labels[clip_id]:
                    problems.append(f"{url}: clip {clip_id} labels {clip['labels']}")
    return problems


def report_crowd(summary: dict[str, object]) -> None:
    print("\ncrowd test:", json.dumps(summary, indent=2))
    if CROWD_REPORT:
        Path(CROWD_REPORT).write_text(json.dumps(summary, indent=2) + "\n")


def test_a_crowd_on_one_server(tmp_path: Path) -> None:
    data_dir = tmp_path / "data"
    # Eight clients from one address: more than the anonymous per-client share of heavy work.
    env = {"MOCAP_MAX_K": "100000", "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64"}
    with LiveServer(data_dir, env) as server:
        ledger, elapsed = run_crowd([server.url], CROWD_SECONDS)
        problems = crowd_problems(ledger, [server.url])
        log = server.log()
    problems += database_problems(data_dir, 3)
    report_crowd(crowd_summary(ledger, elapsed, 1))
    assert not ledger.record.errors, ledger.record.errors[:10]
    assert not problems, problems
    assert len(ledger.stored) > 10 and ledger.deleted and ledger.labels
    assert "Traceback" not in log, log[-3000:]


@contextmanager
def two_replicas(tmp_path: Path, database_url: str) -> Iterator[list[LiveServer]]:
    """Two live servers on one PostgreSQL database, each with its own data directory."""
    env = {
        "MOCAP_DATABASE_URL": database_url,
        "MOCAP_INDEX_REFRESH_SECONDS": "0.1",
        "MOCAP_MAX_K": "100000",
        "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "64",
    }
    servers = [LiveServer(tmp_path / name / "data", env) for name in ("a", "b")]
    for server in servers:
        server.data_dir.parent.mkdir(parents=True)
    try:
        for server in servers:
            server.start()
        yield servers
    finally:
        for server in servers:
            server.stop()


def test_a_crowd_on_two_replicas(postgres_url: str, tmp_path: Path) -> None:
    from tests.hardening.test_replicas import database_problems as postgres_problems

    with two_replicas(tmp_path, postgres_url) as servers:
        urls = [server.url for server in servers]
        ledger, elapsed = run_crowd(urls, CROWD_SECONDS)
        problems = crowd_problems(ledger, urls)
        logs = [server.log() for server in servers]
    problems += postgres_problems(postgres_url)
    report_crowd(crowd_summary(ledger, elapsed, 2))
    assert not ledger.record.errors, ledger.record.errors[:10]
    assert not problems, problems
    assert len(ledger.stored) > 10 and ledger.deleted and ledger.labels
    for log in logs:
        assert "Traceback" not in log, log[-3000:]
