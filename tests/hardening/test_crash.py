"""kill -9 the real server while uploads and deletes are in flight; after every restart
nothing acknowledged is lost, nothing is half present, and the indexes agree with the database.

Rounds: ``MOCAP_CRASH_ROUNDS`` (default 5 in CI; docs/hardening.md records longer runs). Each
round starts ``mocap-index serve`` on the same data directory, checks everything, lets 3
uploaders and 1 deleter run for a random 0.3-2.5 s and kills the server with SIGKILL.
"""

from __future__ import annotations

import os
import random
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from tests.hardening.live import (
    LiveServer,
    all_clips,
    database_problems,
    service_problems,
    unique_upload,
)

ROUNDS = int(os.environ.get("MOCAP_CRASH_ROUNDS", "5"))
SEED = int(os.environ.get("MOCAP_CRASH_SEED", "6"))
DESCRIPTORS = 3  # posture, kinetic, motion: checked against GET /descriptors below


@dataclass
class Ledger:
    """What the clients were told: the server must honour every acknowledgement."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    present: dict[int, str] = field(default_factory=dict)  # acknowledged upload -> hash
    deleted: set[int] = field(default_factory=set)  # acknowledged delete
    unsure: set[int] = field(default_factory=set)  # delete cut off by the kill
    next_clip: int = 0
    uploads: int = 0
    deletes: int = 0
    cut_off: int = 0
    errors: list[str] = field(default_factory=list)  # wrong answers seen by the clients

    def new_number(self) -> int:
        with self.lock:
            self.next_clip += 1
            return self.next_clip


def uploader(url: str, ledger: Ledger, stop: threading.Event) -> None:
    with httpx.Client(base_url=url, timeout=20) as client:
        while not stop.is_set():
            upload = unique_upload(ledger.new_number())
            try:
                response = client.post("/clips", files=upload)
            except httpx.HTTPError:
                with ledger.lock:
                    ledger.cut_off += 1
                return  # the server is gone
            if response.status_code != 201:
                ledger.errors.append(f"upload: {response.status_code} {response.text[:200]}")
                continue
            clip = response.json()
            with ledger.lock:
                ledger.present[clip["id"]] = clip["content_hash"]
                ledger.uploads += 1


def deleter(url: str, ledger: Ledger, stop: threading.Event, rng: random.Random) -> None:
    with httpx.Client(base_url=url, timeout=20) as client:
        while not stop.is_set():
            with ledger.lock:
                candidates = sorted(ledger.present)
            if len(candidates) < 3:
                time.sleep(0.02)
                continue
            clip_id = rng.choice(candidates)
            with ledger.lock:
                ledger.present.pop(clip_id)
            try:
                response = client.delete(f"/clips/{clip_id}")
            except httpx.HTTPError:
                with ledger.lock:
                    ledger.unsure.add(clip_id)
                    ledger.cut_off += 1
                return
            if response.status_code != 204:
                ledger.errors.append(f"delete {clip_id}: {response.status_code} {response.text}")
                continue
            with ledger.lock:
                ledger.deleted.add(clip_id)
                ledger.deletes += 1
            time.sleep(rng.uniform(0, 0.1))


def check_everything(server: LiveServer, ledger: Ledger, data_dir: Path) -> None:
    with httpx.Client(base_url=server.url, timeout=60) as client:
        assert len(client.get("/descriptors").json()["descriptors"]) == DESCRIPTORS
        problems = service_problems(client)
        clips = all_clips(client)
        for clip_id, content_hash in ledger.present.items():
            if clip_id not in clips:
                problems.append(f"acknowledged clip {clip_id} is lost")
            elif clips[clip_id]["content_hash"] != content_hash:
                problems.append(f"clip {clip_id} changed content")
        back = ledger.deleted & set(clips)
        if back:
            problems.append(f"acknowledged deletes came back: {sorted(back)[:5]}")
        for clip_id in sorted(ledger.present)[:5]:  # downloads read the stored files
            if client.get(f"/clips/{clip_id}/file").status_code != 200:
                problems.append(f"clip {clip_id} cannot be downloaded")
    problems += database_problems(data_dir, DESCRIPTORS)
    assert not problems, "\n".join(problems) + f"\n--- server log ---\n{server.log()[-3000:]}"
    # A delete cut off by the kill either happened or did not; from now on it is known.
    for clip_id in ledger.unsure:
        if clip_id in clips:
            ledger.present[clip_id] = clips[clip_id]["content_hash"]
    ledger.unsure.clear()


def test_kill_9_during_uploads_and_deletes(tmp_path: Path) -> None:
    rng = random.Random(SEED)
    data_dir = tmp_path / "data"
    # One process writes here, so unreferenced files may go at once (see README).
    env = {"MOCAP_ORPHAN_FILE_GRACE_SECONDS": "0", "MOCAP_MAX_K": "100000"}
    server = LiveServer(data_dir, env)
    ledger = Ledger()
    started = time.monotonic()
    try:
        for _round in range(ROUNDS):
            server.start()
            check_everything(server, ledger, data_dir)
            stop = threading.Event()
            threads = [
                threading.Thread(target=uploader, args=(server.url, ledger, stop)) for _ in range(3)
            ]
            threads.append(
                threading.Thread(
                    target=deleter, args=(server.url, ledger, stop, random.Random(rng.random()))
                )
            )
            uploads, deletes = ledger.uploads, ledger.deletes
            could_delete = len(ledger.present) >= 3
            for thread in threads:
                thread.start()
            time.sleep(rng.uniform(0.3, 2.5))
            # However loaded the machine, each round acknowledges something before its kill
            # (and deletes once there is something to delete): the kill still falls mid-request.
            progress_by = time.monotonic() + 60
            while time.monotonic() < progress_by and (
                ledger.uploads == uploads or (could_delete and ledger.deletes == deletes)
            ):
                time.sleep(0.05)
            server.kill()
            stop.set()
            for thread in threads:
                thread.join(timeout=60)
                assert not thread.is_alive(), "a client thread hung"
            assert not ledger.errors, ledger.errors[:5]
        server.start()
        check_everything(server, ledger, data_dir)
    finally:
        server.stop()
    elapsed = time.monotonic() - started
    print(
        f"\ncrash test: {ROUNDS} kills in {elapsed:.0f} s; {ledger.uploads} uploads and "
        f"{ledger.deletes} deletes acknowledged, {ledger.cut_off} requests cut off; "
        f"{len(ledger.present)} clips at the end"
    )
    assert ledger.uploads > 0 and ledger.deletes > 0
