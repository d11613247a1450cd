"""``mocap-index serve --workers 2``: two processes answer on one port (forked from the
server's process after it imported the application), each holding its own indexes, and
whichever answers a request sees every acknowledged upload and delete (within
``MOCAP_INDEX_REFRESH_SECONDS``), for clip and moment searches alike; stopping the server
stops both."""

from __future__ import annotations

import os
import time
from pathlib import Path

import httpx

from tests.hardening.live import LiveServer, service_problems, unique_bvh

REFRESH = 0.1
CLIPS = 6
# What the README promises: another process's change is found within the refresh + 1 s.
SETTLE = REFRESH + 1.0
QUERIES = 12  # each on a new connection: the kernel hands them to either worker


def workers_of(pid: int) -> list[int]:
    """The worker processes of server ``pid`` (its children but multiprocessing's resource
    tracker, if any: the workers are forked copies of the server's process), once both have
    started."""
    deadline = time.monotonic() + 60
    while True:
        found = []
        for child in Path(f"/proc/{pid}/task/{pid}/children").read_text().split():
            command = Path(f"/proc/{child}/cmdline").read_bytes()
            if b"resource_tracker" not in command:
                found.append(int(child))
        if len(found) >= 2 or time.monotonic() > deadline:
            return found
        time.sleep(0.1)


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return Path(f"/proc/{pid}").exists() and "zombie" not in Path(f"/proc/{pid}/status").read_text()


def fresh_get(url: str, path: str, **params: object) -> httpx.Response:
    with httpx.Client(base_url=url, timeout=30) as client:  # a new connection
        return client.get(path, params=params)


def test_two_workers_answer_alike_and_stop_together(tmp_path: Path) -> None:
    server = LiveServer(
        tmp_path / "data",
        env={"MOCAP_INDEX_REFRESH_SECONDS": str(REFRESH)},
        args=("--workers", "2"),
    )
    with server:
        assert server.process is not None
        workers = workers_of(server.process.pid)
        assert len(workers) == 2, server.log()
        # Forked from the server's process, which imported the application once (a spawned
        # worker runs multiprocessing's spawn_main and imports it all again: issue 23).
        own = Path(f"/proc/{server.process.pid}/cmdline").read_bytes()
        assert all(Path(f"/proc/{w}/cmdline").read_bytes() == own for w in workers)
        ids = []
        with httpx.Client(base_url=server.url, timeout=30) as client:
            for n in range(CLIPS):
                response = client.post("/clips", files={"file": (f"walk_{n}.bvh", unique_bvh(n))})
                assert response.status_code == 201, response.text
                ids.append(response.json()["id"])
        time.sleep(SETTLE)
        for n in range(QUERIES):
            query = ids[n % CLIPS]
            found = fresh_get(server.url, "/search", clip=query, k=100)
            assert found.status_code == 200, found.text
            assert {hit["id"] for hit in found.json()["results"]} == set(ids) - {query}
            moments = fresh_get(server.url, "/search/moments", clip=query, k=CLIPS)
            assert moments.status_code == 200, moments.text
            assert {hit["id"] for hit in moments.json()["results"]} <= set(ids)
            assert moments.json()["results"], "no moment found"
        with httpx.Client(base_url=server.url, timeout=30) as client:
            assert client.delete(f"/clips/{ids[0]}").status_code == 204
        time.sleep(SETTLE)
        for _ in range(QUERIES):
            found = fresh_get(server.url, "/search", clip=ids[1], k=100)
            assert {hit["id"] for hit in found.json()["results"]} == set(ids[2:])
            moments = fresh_get(server.url, "/search/moments", clip=ids[1], k=CLIPS)
            assert ids[0] not in {hit["id"] for hit in moments.json()["results"]}
            assert fresh_get(server.url, f"/clips/{ids[0]}").status_code == 404
        with httpx.Client(base_url=server.url, timeout=30) as client:
            assert service_problems(client) == []
    deadline = time.monotonic() + 20
    while any(alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(alive(pid) for pid in workers), "a worker outlived the server"


def test_serve_refuses_a_bad_worker_count(tmp_path: Path) -> None:
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-m", "app.cli", "serve", "--workers", "0", "--data-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and "--workers must be between 1 and 64" in done.stderr
