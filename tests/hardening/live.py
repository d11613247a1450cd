"""A real ``mocap-index serve`` in a subprocess on loopback, and unique real clips to feed it.

Every wait here is bounded: the server must answer ``/health`` within ``START_TIMEOUT``
seconds or the test fails with the server's log.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

REPO_ROOT = Path(__file__).resolve().parents[2]
FIXTURES = REPO_ROOT / "tests" / "fixtures"
START_TIMEOUT = 90.0

BVH_TEXT = (FIXTURES / "cmu_mb_02_01_first41.bvh").read_text()
ASF_BYTES = (FIXTURES / "cmu_02.asf").read_bytes()
AMC_TEXT = (FIXTURES / "cmu_02_01_first40.amc").read_text()
BVH_FIRST_VALUE = "10.4194 16.7048 -30.1003"  # root position of frame 1 in both fixtures
assert BVH_FIRST_VALUE in BVH_TEXT
AMC_FIRST_VALUE = "root 10.4194 16.7048 -30.1003"
assert AMC_FIRST_VALUE in AMC_TEXT


def unique_bvh(n: int) -> bytes:
    """The real BVH fixture with frame 1's root x moved by ``n`` micro-units: new content."""
    moved = f"{10.4194 + n * 1e-6:.7f} 16.7048 -30.1003"
    return BVH_TEXT.replace(BVH_FIRST_VALUE, moved, 1).encode()


def unique_amc(n: int) -> bytes:
    return AMC_TEXT.replace(
        AMC_FIRST_VALUE, f"root {10.4194 + n * 1e-6:.7f} 16.7048 -30.1003", 1
    ).encode()


def stretched_bvh(frames: int, n: int, text: str = BVH_TEXT) -> bytes:
    """A real BVH (the CMU fixture, or ``text``) played back and forth to ``frames`` frames;
    ``n`` moves frame 1's root a little: new content."""
    head, _, body = text.partition("MOTION")
    lines = [line for line in body.strip().splitlines() if line.strip()]
    frame_time, rows = lines[1], lines[2:]
    order = [*range(len(rows)), *range(len(rows) - 2, 0, -1)]
    chosen = [rows[order[i % len(order)]] for i in range(frames)]
    first = chosen[0].split()
    first[0] = f"{float(first[0]) + n * 1e-4:.4f}"
    chosen[0] = " ".join(first)
    return (f"{head}MOTION\nFrames: {frames}\n{frame_time}\n" + "\n".join(chosen) + "\n").encode()


def unique_upload(n: int) -> dict[str, tuple[str, bytes]]:
    """Upload fields for clip number ``n``: a BVH, or every third one an ASF + AMC."""
    if n % 3 == 2:
        return {"skeleton": ("02.asf", ASF_BYTES), "motion": (f"02_01_{n}.amc", unique_amc(n))}
    return {"file": (f"walk_{n}.bvh", unique_bvh(n))}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class LiveServer:
    """``mocap-index serve`` on ``127.0.0.1:<free port>`` over ``data_dir``."""

    data_dir: Path
    env: dict[str, str] = field(default_factory=dict)
    args: tuple[str, ...] = ()  # more options of ``serve`` (e.g. --workers 2)
    port: int = 0
    process: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None
    starts: int = 0

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> LiveServer:
        self.port = free_port()
        self.starts += 1
        self.log_path = self.data_dir.parent / f"server-{self.starts}.log"
        env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
        env.update({"OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1", **self.env})
        with open(self.log_path, "wb") as log:
            self.process = subprocess.Popen(
                [
                    *(sys.executable, "-m", "app.cli", "serve", "--port", str(self.port)),
                    *("--host", "127.0.0.1", "--data-dir", str(self.data_dir)),
                    *self.args,
                ],
                cwd=REPO_ROOT,
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        deadline = time.monotonic() + START_TIMEOUT
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"the server exited at start:\n{self.log()}")
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{self.url}/health", timeout=2).status_code == 200:
                    return self
            time.sleep(0.1)
        self.kill()
        raise RuntimeError(f"the server did not answer /health in {START_TIMEOUT} s:\n{self.log()}")

    def kill(self) -> None:
        """SIGKILL: no shutdown code runs, as in a crash or an OOM kill."""
        if self.process is not None and self.process.poll() is None:
            os.kill(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=30)

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.kill()

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path else ""

    def __enter__(self) -> LiveServer:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()


def raw_request(
    server: LiveServer, head: bytes, body_chunks: list[bytes], timeout: float = 10.0
) -> bytes:
    """Send a request by hand; returns what the server answered within ``timeout`` seconds
    (``b""``: nothing). The body may be cut short: the server must answer from the head."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=timeout) as sock:
        sock.sendall(head)
        for chunk in body_chunks:
            try:
                sock.sendall(chunk)
            except OSError:  # the server answered and closed: the rest is refused
                break
        answer = b""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                data = sock.recv(65536)
            except TimeoutError:
                break
            if not data:
                break
            answer += data
            head_end = answer.find(b"\r\n\r\n")
            if head_end >= 0:
                length = 0
                for line in answer[:head_end].split(b"\r\n")[1:]:
                    name, _, value = line.partition(b":")
                    if name.strip().lower() == b"content-length":
                        length = int(value)
                if len(answer) >= head_end + 4 + length:
                    break
        return answer


def percentiles(values: list[float]) -> dict[str, float]:
    """p50/p95/p99/max of ``values`` (seconds) in milliseconds."""
    if not values:
        return {}
    ordered = sorted(values)

    def at(q: float) -> float:
        return round(1000 * ordered[min(len(ordered) - 1, int(q * len(ordered)))], 1)

    return {"p50": at(0.50), "p95": at(0.95), "p99": at(0.99), "max": round(1000 * ordered[-1], 1)}


# -- what the data directory must look like -----------------------------------------------


def database_problems(data_dir: Path, descriptor_count: int) -> list[str]:
    """Integrity of the SQLite file and of clips vs rows vs stored files (read-only)."""
    db = data_dir / "mocap-index.sqlite3"
    problems = []
    with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=30)) as con:
        integrity = con.execute("PRAGMA integrity_check").fetchall()
        if integrity != [("ok",)]:
            problems.append(f"integrity_check: {integrity[:5]}")
        foreign = con.execute("PRAGMA foreign_key_check").fetchall()
        if foreign:
            problems.append(f"foreign_key_check: {foreign[:5]}")
        partial = con.execute(
            "SELECT c.id, COUNT(d.name) FROM clips c LEFT JOIN clip_descriptors d "
            "ON d.clip_id = c.id GROUP BY c.id HAVING COUNT(d.name) != ?",
            (descriptor_count,),
        ).fetchall()
        if partial:
            problems.append(f"clips without all {descriptor_count} vectors: {partial[:5]}")
        for table in ("clip_descriptors", "clip_files", "clip_labels"):
            orphans = con.execute(
                f"SELECT COUNT(*) FROM {table} t LEFT JOIN clips c ON c.id = t.clip_id "
                "WHERE c.id IS NULL"
            ).fetchone()[0]
            if orphans:
                problems.append(f"{orphans} {table} rows without a clip")
        no_files = con.execute(
            "SELECT c.id FROM clips c LEFT JOIN clip_files f ON f.clip_id = c.id "
            "WHERE f.clip_id IS NULL"
        ).fetchall()
        if no_files:
            problems.append(f"clips without files: {no_files[:5]}")
        referenced = {row[0] for row in con.execute("SELECT sha256 FROM clip_files")}
    files_dir = data_dir / "files"
    on_disk = {p.name for p in files_dir.glob("??/*") if not p.name.startswith(".")}
    temporary = list(files_dir.glob("??/.*"))
    if referenced - on_disk:
        problems.append(f"rows naming missing files: {sorted(referenced - on_disk)[:3]}")
    if on_disk - referenced:
        problems.append(f"stored files no clip refers to: {sorted(on_disk - referenced)[:3]}")
    if temporary:
        problems.append(f"temporary files left: {temporary[:3]}")
    return problems


def all_clips(client: httpx.Client) -> dict[int, dict[str, Any]]:
    clips: dict[int, dict[str, Any]] = {}
    offset = 0
    while True:
        page = client.get("/clips", params={"limit": 500, "offset": offset}).json()
        clips.update({c["id"]: c for c in page["items"]})
        offset += 500
        if offset >= page["total"]:
            return clips


def service_problems(client: httpx.Client) -> list[str]:
    """What /health, /clips and /search say must agree: every clip in every index."""
    problems = []
    health = client.get("/health").json()
    clips = all_clips(client)
    if health["clips"] != len(clips):
        problems.append(f"/health counts {health['clips']} clips, /clips lists {len(clips)}")
    for name, index in health["indexes"].items():
        if index["size"] != len(clips):
            problems.append(f"index {name} holds {index['size']} vectors for {len(clips)} clips")
    hashes = [c["content_hash"] for c in clips.values()]
    if len(set(hashes)) != len(hashes):
        problems.append("two clips with the same content")
    if len(clips) >= 2:
        query = min(clips)
        for name in health["indexes"]:
            response = client.get(
                "/search", params={"clip": query, "k": len(clips), "descriptor": name}
            )
            if response.status_code != 200:
                problems.append(f"search under {name}: {response.status_code} {response.text}")
                continue
            found = {hit["id"] for hit in response.json()["results"]} | {query}
            if found != set(clips):
                missing = sorted(set(clips) - found)[:5]
                extra = sorted(found - set(clips))[:5]
                problems.append(f"search under {name}: missing {missing}, unknown {extra}")
    return problems
