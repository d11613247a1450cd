"""``mocap-index import`` as a process: killed half way and run again, interrupted, and
running beside a live server that must see the new clips without a restart."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.api.test_restart import running_server
from tests.conftest import REPO_ROOT

FIXTURE = "bandai_walk_normal_001_first40.bvh"


def unique_copies(source: Path, folder: Path, count: int) -> list[Path]:
    """``count`` distinct clips: the same motion, each file one more trailing newline."""
    folder.mkdir(parents=True, exist_ok=True)
    data = source.read_bytes()
    paths = []
    for i in range(count):
        path = folder / f"take_{i:04d}.bvh"
        path.write_bytes(data + b"\n" * (i + 1))
        paths.append(path)
    return paths


def import_command(data_dir: Path, *paths: Path, extra: tuple[str, ...] = ()) -> list[str]:
    return [
        sys.executable,
        "-m",
        "app.cli",
        "import",
        "--no-progress",
        "--data-dir",
        str(data_dir),
        *extra,
        *map(str, paths),
    ]


def environment() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}


def clip_counts(data_dir: Path) -> tuple[int, int]:
    """(clips, distinct content hashes); (0, 0) before the schema exists."""
    db = sqlite3.connect(data_dir / "mocap-index.sqlite3", timeout=30)
    try:
        row = db.execute("SELECT count(*), count(DISTINCT content_hash) FROM clips").fetchone()
        return int(row[0]), int(row[1])
    except sqlite3.OperationalError:
        return 0, 0
    finally:
        db.close()


def wait_until_some_committed(data_dir: Path, process: subprocess.Popen, total: int) -> int:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if process.poll() is not None:
            pytest.fail(f"import ended before it could be stopped ({process.returncode})")
        if (data_dir / "mocap-index.sqlite3").exists():
            stored, _ = clip_counts(data_dir)
            if 0 < stored < total:
                return stored
        time.sleep(0.02)
    pytest.fail("no batch was committed within 60 s")


def processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if text.encode() in (entry / "cmdline").read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


@pytest.mark.parametrize("stop", [signal.SIGKILL, signal.SIGINT])
def test_stopped_half_way_then_run_again(
    stop: signal.Signals, tmp_path: Path, fixtures_dir: Path
) -> None:
    # Enough batches of 8 to stop between, the rerun importing the rest: the import runs ~200
    # clips a second, so with 160 a loaded machine could let it finish before the signal.
    total = 400
    unique_copies(fixtures_dir / FIXTURE, tmp_path / "clips", total)
    data_dir = tmp_path / "data"
    command = import_command(
        data_dir, tmp_path / "clips", extra=("--workers", "1", "--batch-size", "8")
    )
    process = subprocess.Popen(
        command, cwd=REPO_ROOT, env=environment(), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    committed = wait_until_some_committed(data_dir, process, total)
    process.send_signal(stop)
    out, err = process.communicate(timeout=60)
    if stop == signal.SIGINT:
        assert process.returncode == 130, err
        assert "interrupted: imported" in out.decode()
        assert "run the same command again" in err.decode()
    else:
        assert process.returncode == -signal.SIGKILL
    stored, distinct = clip_counts(data_dir)
    assert committed <= stored < total and stored == distinct

    # The workers of the killed run do not outlive it.
    deadline = time.monotonic() + 10
    while processes_mentioning(str(tmp_path / "clips")) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert processes_mentioning(str(tmp_path / "clips")) == []

    again = subprocess.run(command, cwd=REPO_ROOT, env=environment(), capture_output=True)
    assert again.returncode == 0, again.stderr.decode()
    summary = again.stdout.decode()
    assert f"imported {total - stored}, skipped {stored} as duplicates, failed 0" in summary
    assert clip_counts(data_dir) == (total, total)


def test_the_server_sees_clips_imported_by_another_process(
    tmp_path: Path, fixtures_dir: Path
) -> None:
    data_dir = tmp_path / "data"
    first = unique_copies(fixtures_dir / FIXTURE, tmp_path / "first", 3)
    with running_server(data_dir, tmp_path / "server.log") as client:
        response = client.post("/clips", files={"file": (first[0].name, first[0].read_bytes())})
        assert response.status_code == 201, response.text
        uploaded = response.json()["id"]
        assert client.get("/search", params={"clip": uploaded, "k": 5}).json()["results"] == []

        done = subprocess.run(
            import_command(data_dir, tmp_path / "first", fixtures_dir),
            cwd=REPO_ROOT,
            env=environment(),
            capture_output=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr.decode()
        assert "skipped 1 as duplicates" in done.stdout.decode()

        # 2 copies + 9 fixture clips (2 BVH, 1 ASF/AMC, 5 FBX, 1 VRMA) more, no restart.
        deadline = time.monotonic() + 10
        while True:
            found = client.get("/search", params={"clip": uploaded, "k": 20}).json()
            if len(found["results"]) == 11 or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        assert len(found["results"]) == 11
        names = {hit["name"] for hit in found["results"]}
        assert {"take_0001", "take_0002", "cmu_02_01_first40", "cmu_mb_02_01_first41"} <= names
        # The copies differ only by trailing newlines: the same motion, distance 0.
        assert found["results"][0]["distance"] == pytest.approx(0, abs=1e-6)
        for descriptor in ("kinetic", "motion"):
            other = client.get(
                "/search", params={"clip": uploaded, "k": 20, "descriptor": descriptor}
            )
            assert len(other.json()["results"]) == 11
        health = client.get("/health").json()
        assert health["clips"] == 12
        assert {index["size"] for index in health["indexes"].values()} == {12}
        # An upload after the import gets the next id and is found too.
        late = unique_copies(fixtures_dir / FIXTURE, tmp_path / "late", 5)[-1]
        response = client.post("/clips", files={"file": (late.name, late.read_bytes())})
        assert response.status_code == 201 and response.json()["id"] == 13
        found = client.get("/search", params={"clip": 13, "k": 20}).json()["results"]
        assert len(found) == 12
