"""A real server restarted on the same data directory answers searches as before, also when
its index files were deleted or damaged in between (they are rebuilt from the database).

SQLite only (the default a server gets from its data directory): restarts on PostgreSQL, with
and without index files, are tested in tests/hardening/test_replicas.py and
tests/db/test_changes.py."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest

from tests.conftest import REPO_ROOT, SharedData


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@contextmanager
def running_server(data_dir: Path, log: Path) -> Iterator[httpx.Client]:
    """``mocap-index serve`` on a free loopback port; stopped (Ctrl-C) on exit."""
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    command = [sys.executable, "-m", "app.cli", "serve", "--data-dir", str(data_dir)]
    with open(log, "ab") as out:
        process = subprocess.Popen(
            [*command, "--port", str(port)],
            cwd=REPO_ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    try:
        deadline = time.monotonic() + 60
        while True:
            if process.poll() is not None:
                raise AssertionError(f"server exited early:\n{log.read_text()}")
            try:
                if client.get("/health").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise AssertionError(f"server did not start:\n{log.read_text()}")
            time.sleep(0.2)
        yield client
    finally:
        client.close()
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def all_searches(client: httpx.Client, ids: list[int], names: list[str]) -> dict[tuple, list]:
    answers = {}
    for descriptor in names:
        for clip_id in ids:
            response = client.get(
                "/search", params={"clip": clip_id, "k": 5, "descriptor": descriptor}
            )
            assert response.status_code == 200, response.text
            answers[descriptor, clip_id] = [
                (r["id"], r["distance"]) for r in response.json()["results"]
            ]
    return answers


def test_restart_with_missing_or_damaged_indexes(shared_data: SharedData, tmp_path: Path) -> None:
    data_dir, log = tmp_path / "data", tmp_path / "server.log"
    bandai = shared_data("bandai-ds1", "data")
    cmu = shared_data("cmu", "asf-amc", "02")
    with running_server(data_dir, log) as client:
        ids = []
        for path in sorted(bandai.glob("*.bvh"))[::17]:  # 11 clips of various actions
            response = client.post("/clips", files={"file": (path.name, path.read_bytes())})
            assert response.status_code == 201, response.text
            ids.append(response.json()["id"])
        for trial in ("02_01", "02_02"):
            files = {
                "skeleton": ("02.asf", (cmu / "02.asf").read_bytes()),
                "motion": (f"{trial}.amc", (cmu / f"{trial}.amc").read_bytes()),
            }
            response = client.post("/clips", files=files)
            assert response.status_code == 201, response.text
            ids.append(response.json()["id"])
        names = [d["name"] for d in client.get("/descriptors").json()["descriptors"]]
        before = all_searches(client, ids, names)

    index_dir = data_dir / "indexes"
    assert {f"{n}.faiss" for n in names} <= {p.name for p in index_dir.iterdir()}
    (index_dir / "posture.faiss").write_bytes(b"garbage")
    (index_dir / "kinetic.faiss").unlink()
    damaged = bytearray((index_dir / f"{names[-1]}.faiss").read_bytes())
    damaged[-3] ^= 0x55  # a flipped bit among the vectors
    (index_dir / f"{names[-1]}.faiss").write_bytes(bytes(damaged))

    with running_server(data_dir, log) as client:
        health = client.get("/health").json()
        assert health["clips"] == len(ids)
        assert all(index["size"] == len(ids) for index in health["indexes"].values())
        after = all_searches(client, ids, names)

    assert after.keys() == before.keys()
    for key, results in before.items():
        assert [i for i, _ in after[key]] == [i for i, _ in results], key
        assert [d for _, d in after[key]] == pytest.approx([d for _, d in results], rel=1e-6)
    server_log = log.read_text()
    for name in {"posture", "kinetic", names[-1]}:
        assert f"rebuilt the {name} index" in server_log
