"""Two ``mocap-index serve`` replicas, real processes on loopback, on one PostgreSQL database
(each with its own data directory: only the database is shared, as on two machines).

What one stores or deletes, the other finds or stops finding (how soon — within
``MOCAP_INDEX_REFRESH_SECONDS`` + 1 s — is measured by ``bench/bench_visibility.py``); both
take uploads at once (the same content through both is stored once); ``mocap-index import``
runs against the database meanwhile; after a ``kill -9`` of one replica mid-upload and its
restart, every acknowledged clip is present and searchable through both, and each replica's
indexes hold exactly the database's clips.
"""

from __future__ import annotations

import random
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
from sqlalchemy import create_engine, text

from tests.hardening.live import (
    REPO_ROOT,
    LiveServer,
    all_clips,
    service_problems,
    unique_bvh,
    unique_upload,
)
from tests.hardening.test_crash import DESCRIPTORS, Ledger, uploader

REFRESH = 0.1
PROMISE = REFRESH + 1.0  # what the README promises; measured by bench/bench_visibility.py
WAIT_LIMIT = 60.0  # a bound so a broken change feed fails the test instead of hanging it


def found_by_search(client: httpx.Client, query: int) -> set[int]:
    """Every clip a search by ``query`` returns (k = all), plus ``query`` itself."""
    response = client.get("/search", params={"clip": query, "k": 100_000})
    assert response.status_code == 200, response.text
    return {hit["id"] for hit in response.json()["results"]} | {query}


def index_sizes(client: httpx.Client) -> set[int]:
    return {index["size"] for index in client.get("/health").json()["indexes"].values()}


def wait_until(condition: object, what: str) -> float:
    """Seconds until ``condition()`` holds; fails past :data:`WAIT_LIMIT` (never seen: how
    soon is the benchmark's question, on a machine that is not running the whole suite)."""
    started = time.monotonic()
    while True:
        if condition():  # type: ignore[operator]
            return time.monotonic() - started
        elapsed = time.monotonic() - started
        assert elapsed < WAIT_LIMIT, f"{what}: not within {WAIT_LIMIT} s"
        time.sleep(0.02)


def database_problems(url: str) -> list[str]:
    """Clips vs vectors vs stored files (rows of ``blobs``), read straight from PostgreSQL."""
    engine = create_engine(url)
    problems = []
    try:
        with engine.connect() as db:
            partial = db.execute(
                text(
                    "SELECT c.id FROM clips c LEFT JOIN clip_descriptors d ON d.clip_id = c.id "
                    "GROUP BY c.id HAVING count(d.name) != :n"
                ),
                {"n": DESCRIPTORS},
            ).all()
            if partial:
                problems.append(f"clips without all vectors: {partial[:5]}")
            missing = db.execute(
                text(
                    "SELECT f.sha256 FROM clip_files f LEFT JOIN blobs b ON b.sha256 = f.sha256 "
                    "WHERE b.sha256 IS NULL"
                )
            ).all()
            if missing:
                problems.append(f"rows naming missing files: {missing[:3]}")
            orphans = db.execute(
                text(
                    "SELECT b.sha256 FROM blobs b WHERE NOT EXISTS "
                    "(SELECT 1 FROM clip_files f WHERE f.sha256 = b.sha256)"
                )
            ).all()
            if orphans:
                problems.append(f"stored files no clip refers to: {orphans[:3]}")
    finally:
        engine.dispose()
    return problems


def test_two_replicas_on_one_postgres_database(postgres_url: str, tmp_path: Path) -> None:
    env = {
        "MOCAP_DATABASE_URL": postgres_url,
        "MOCAP_INDEX_REFRESH_SECONDS": str(REFRESH),
        "MOCAP_MAX_K": "100000",
        # Nothing is uploading when a replica starts here, so files a kill left without a
        # clip may go at once (in production the grace spares other replicas' uploads).
        "MOCAP_ORPHAN_FILE_GRACE_SECONDS": "0",
    }
    a = LiveServer(tmp_path / "a" / "data", env)
    b = LiveServer(tmp_path / "b" / "data", env)
    a.data_dir.parent.mkdir(parents=True)
    b.data_dir.parent.mkdir(parents=True)
    waits: list[float] = []
    try:
        a.start()
        b.start()
        with (
            httpx.Client(base_url=a.url, timeout=60) as ca,
            httpx.Client(base_url=b.url, timeout=60) as cb,
        ):
            # Stored through A: found through B.
            ids = []
            for n in range(6):
                response = ca.post("/clips", files=unique_upload(n))
                assert response.status_code == 201, response.text
                clip_id = response.json()["id"]
                ids.append(clip_id)
                if len(ids) >= 2:
                    waits.append(
                        wait_until(
                            lambda c=clip_id: c in found_by_search(cb, ids[0]), "upload on B"
                        )
                    )
            assert cb.get(f"/clips/{ids[-1]}").status_code == 200
            assert cb.get(f"/clips/{ids[4]}/file").content == unique_upload(4)["file"][1]

            # Deleted through A: gone from B's searches and indexes.
            assert ca.delete(f"/clips/{ids[1]}").status_code == 204
            waits.append(
                wait_until(lambda: ids[1] not in found_by_search(cb, ids[0]), "delete on B")
            )
            # (a search skips a deleted clip at once; B's indexes drop it at its next refresh)
            waits.append(wait_until(lambda: index_sizes(cb) == {5}, "delete in B's indexes"))

            # Both take uploads at once; the same content through both is one clip.
            ledger = Ledger()
            ledger.next_clip = 100
            same = {"file": ("same.bvh", unique_bvh(99))}
            answers: list[int] = []

            def upload_to(client_url: str, count: int) -> None:
                with httpx.Client(base_url=client_url, timeout=60) as client:
                    answer = client.post("/clips", files=same)
                    assert answer.status_code in (200, 201), answer.text
                    answers.append(answer.json()["id"])
                    for _ in range(count):
                        upload = unique_upload(ledger.new_number())
                        response = client.post("/clips", files=upload)
                        assert response.status_code == 201, response.text
                        with ledger.lock:
                            ledger.present[response.json()["id"]] = response.json()["content_hash"]

            threads = [threading.Thread(target=upload_to, args=(u, 6)) for u in (a.url, b.url)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join(timeout=120)
            assert len(ledger.present) == 12 and len(set(answers)) == 1, answers

            # `mocap-index import` against the same database while both serve.
            folder = tmp_path / "import"
            folder.mkdir()
            for n in range(3):
                (folder / f"imported_{n}.bvh").write_bytes(unique_bvh(500 + n))
            imported = subprocess.run(
                [
                    *(sys.executable, "-m", "app.cli", "import", str(folder)),
                    *("--workers", "1", "--database-url", postgres_url),
                    *("--data-dir", str(tmp_path / "importer")),
                ],
                cwd=REPO_ROOT,
                capture_output=True,
                text=True,
                timeout=300,
            )
            assert imported.returncode == 0, imported.stdout + imported.stderr
            for client in (ca, cb):
                names = {c["name"] for c in all_clips(client).values()}
                assert {f"imported_{n}" for n in range(3)} <= names
            wait_until(lambda: len(found_by_search(cb, ids[0])) == 5 + 13 + 3, "import on B")

        # kill -9 of A while it takes uploads, then its restart.
        ledger = Ledger()
        ledger.next_clip = 1000
        stop = threading.Event()
        threads = [threading.Thread(target=uploader, args=(a.url, ledger, stop)) for _ in range(3)]
        for thread in threads:
            thread.start()
        time.sleep(random.Random(15).uniform(0.8, 1.6))
        a.kill()
        stop.set()
        for thread in threads:
            thread.join(timeout=60)
        assert not ledger.errors, ledger.errors[:5]
        assert ledger.uploads > 0
        a.start()
        for server in (a, b):
            with httpx.Client(base_url=server.url, timeout=60) as client:
                problems = service_problems(client)  # every clip in every index, searchable
                clips = all_clips(client)
                lost = set(ledger.present) - set(clips)
                if lost:
                    problems.append(f"acknowledged clips lost: {sorted(lost)[:5]}")
                assert not problems, "\n".join(problems) + server.log()[-3000:]
        assert not database_problems(postgres_url)
    finally:
        a.stop()
        b.stop()
    print(
        f"\nreplicas: slowest cross-replica visibility {max(waits) * 1000:.0f} ms "
        f"(promised {PROMISE * 1000:.0f} ms); {ledger.uploads} uploads acknowledged before "
        f"the kill, {ledger.cut_off} cut off"
    )
