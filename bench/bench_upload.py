"""Upload benchmark: ``POST /clips`` of the Bandai dataset 1 files from 4 concurrent clients.

Run from the repository root::

    .venv/bin/python bench/bench_upload.py [--clients 4] [--rounds 3] [--data PATH]

Starts ``mocap-index serve`` (default settings) on a free loopback port with an empty
temporary data directory, then ``--clients`` threads, each with its own HTTP connection, upload
the 174 files, ``--rounds`` times; every round changes each file by one trailing newline, so
every upload is new content that is parsed, described and stored (201). Reports clips/s per
round and overall, and checks every answer and the final clip count. Target: at least 40
clips/s. The data folder is ``../shared/data`` or ``$MOCAP_SHARED_DATA``.
"""

from __future__ import annotations

import argparse
import os
import queue
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
TARGET = 40.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def start_server(data_dir: Path, port: int, log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    command = [str(ROOT / ".venv" / "bin" / "mocap-index"), "serve", "--data-dir", str(data_dir)]
    with open(log, "wb") as out:
        process = subprocess.Popen(
            [*command, "--port", str(port)], cwd=ROOT, env=env, stdout=out, stderr=out
        )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"server exited:\n{log.read_text()}")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=5).status_code == 200:
                return process
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    process.kill()
    raise SystemExit("server did not start within 60 s")


def upload_round(
    base: str, files: list[tuple[str, bytes]], clients: int
) -> tuple[float, list[str]]:
    work: queue.Queue[tuple[str, bytes]] = queue.Queue()
    for item in files:
        work.put(item)
    problems: list[str] = []

    def client() -> None:
        with httpx.Client(base_url=base, timeout=120) as http:
            while True:
                try:
                    name, data = work.get_nowait()
                except queue.Empty:
                    return
                response = http.post("/clips", files={"file": (name, data)})
                if response.status_code != 201:
                    problems.append(f"{name}: {response.status_code} {response.text[:200]}")

    threads = [threading.Thread(target=client) for _ in range(clients)]
    started = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return time.perf_counter() - started, problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--data", type=Path, help="default: <shared data>/bandai-ds1")
    args = parser.parse_args()
    source = args.data or shared_data() / "bandai-ds1"
    paths = sorted(source.rglob("*.bvh"))
    if not paths:
        print(f"no BVH files under {source}", file=sys.stderr)
        return 2
    originals = [(p.name, p.read_bytes()) for p in paths]
    print(f"machine: {machine()}")
    print(f"data: {source} ({len(paths)} BVH, {sum(len(d) for _, d in originals) / 1e6:.1f} MB)")
    rates = []
    with tempfile.TemporaryDirectory(prefix="mocap-bench-upload-") as tmp:
        port = free_port()
        log = Path(tmp) / "server.log"
        server = start_server(Path(tmp) / "data", port, log)
        base = f"http://127.0.0.1:{port}"
        try:
            total_seconds = 0.0
            for round_number in range(args.rounds):
                files = [(name, data + b"\n" * round_number) for name, data in originals]
                seconds, problems = upload_round(base, files, args.clients)
                if problems:
                    print("\n".join(problems[:10]), file=sys.stderr)
                    return 1
                total_seconds += seconds
                rates.append(len(files) / seconds)
                print(
                    f"round {round_number + 1}: {len(files)} uploads in {seconds:.2f} s = "
                    f"{rates[-1]:.1f} clips/s"
                )
            health = httpx.get(f"{base}/health", timeout=30).json()
            expected = len(originals) * args.rounds
            assert health["clips"] == expected, health
            assert all(i["size"] == expected for i in health["indexes"].values()), health
        finally:
            server.send_signal(signal.SIGINT)
            try:
                server.wait(timeout=30)
            except subprocess.TimeoutExpired:
                server.kill()
    overall = len(originals) * args.rounds / total_seconds
    print(
        f"{args.clients} clients: {overall:.1f} clips/s overall (rounds: "
        f"{', '.join(f'{r:.1f}' for r in rates)}; target {TARGET:.0f})"
    )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if overall >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
