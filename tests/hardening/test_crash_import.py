"""kill -9 ``mocap-index import`` mid-run, again and again: every batch it committed is whole,
nothing is half stored, a rerun finishes the job without duplicates, and the server started
afterwards agrees with the database (every clip in every index).

Rounds: ``MOCAP_CRASH_ROUNDS`` (default 4 here); docs/hardening.md records longer runs.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from app.discovery import content_hash_of_bytes
from tests.hardening.live import (
    ASF_BYTES,
    REPO_ROOT,
    LiveServer,
    all_clips,
    database_problems,
    service_problems,
    unique_amc,
    unique_bvh,
)

ROUNDS = int(os.environ.get("MOCAP_CRASH_ROUNDS", "4"))
SEED = int(os.environ.get("MOCAP_CRASH_SEED", "6"))
BVH_CLIPS = 1000
AMC_CLIPS = 200


def make_source(folder: Path) -> set[str]:
    """Unique real clips in the layouts import reads; returns their content hashes."""
    (folder / "bvh").mkdir(parents=True)
    (folder / "02").mkdir()
    hashes = set()
    for n in range(BVH_CLIPS):
        data = unique_bvh(n)
        (folder / "bvh" / f"walk_{n}.bvh").write_bytes(data)
        hashes.add(content_hash_of_bytes(data))
    (folder / "02" / "02.asf").write_bytes(ASF_BYTES)
    for n in range(AMC_CLIPS):
        data = unique_amc(n)
        (folder / "02" / f"02_{n:03d}.amc").write_bytes(data)
        hashes.add(content_hash_of_bytes(data, ASF_BYTES))
    return hashes


def start_import(source: Path, data_dir: Path, log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env["OMP_NUM_THREADS"] = "1"
    with open(log, "ab") as out:
        return subprocess.Popen(
            [
                *(sys.executable, "-m", "app.cli", "import", str(source)),
                *("--data-dir", str(data_dir), "--workers", "1", "--batch-size", "8"),
                "--no-progress",
            ],
            cwd=REPO_ROOT,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )


def check(data_dir: Path, log: Path) -> dict[int, dict[str, object]]:
    """Start the server on the data, check everything, stop it; returns the clips."""
    env = {"MOCAP_ORPHAN_FILE_GRACE_SECONDS": "0", "MOCAP_MAX_K": "100000"}
    with (
        LiveServer(data_dir, env) as server,
        httpx.Client(base_url=server.url, timeout=60) as client,
    ):
        problems = service_problems(client)
        clips = all_clips(client)
        server_log = server.log()
    problems += database_problems(data_dir, 3)
    assert not problems, "\n".join(problems) + "\n" + log.read_text()[-2000:] + server_log[-2000:]
    return clips


def test_kill_9_during_import(tmp_path: Path) -> None:
    rng = random.Random(SEED)
    expected = make_source(tmp_path / "source")
    data_dir = tmp_path / "data"
    log = tmp_path / "import.log"
    killed_with = []
    for _round in range(ROUNDS):
        process = start_import(tmp_path / "source", data_dir, log)
        time.sleep(rng.uniform(0.6, 1.8))
        if process.poll() is None:
            os.kill(process.pid, signal.SIGKILL)
        process.wait(timeout=60)
        clips = check(data_dir, log)
        killed_with.append(len(clips))
        assert {c["content_hash"] for c in clips.values()} <= expected
    # a run to the end stores the rest, each clip once
    finished = start_import(tmp_path / "source", data_dir, log)
    assert finished.wait(timeout=300) == 0, log.read_text()[-3000:]
    clips = check(data_dir, log)
    assert {c["content_hash"] for c in clips.values()} == expected
    assert len(clips) == len(expected)
    print(f"\nimport crash test: killed with {killed_with} clips stored, then {len(clips)}")
