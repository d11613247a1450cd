"""A crowd of large uploads at once against a real server with the default settings: the
server's memory stays within the documented bound and ``/health`` keeps answering (issue 21).

Run from the repository root::

    .venv/bin/python bench/bench_busy.py [--large 40] [--at-cap 12]

Two rounds, each sent at the same moment while another process times ``/health`` every 50 ms
and the server's RSS (all its processes) is sampled every 50 ms:

1. ``--large`` uploads of real CMU takes (``cmu/bvh-mb``, 2-4 MB each, each made new
   content by trailing newlines);
2. ``--at-cap`` uploads just under ``MOCAP_MAX_FRAME_VALUES`` (a real CMU take played back
   and forth to 99 % of the cap: 58,000 frames, 43 MB).

Every answer must be 201/200/503 (``busy``, with Retry-After), ``/health`` within 1 s, and
the RSS growth within ``describe slots x describe_bytes`` (``app/api/limits.py``): the bound
docs/hardening.md gives. Before the bound, 12 uploads at the cap took a server to 7.5 GB.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx
from bench_search import Server, rss_bytes
from common import ROOT, machine, shared_data  # bench/common.py (scripts run from bench/)

sys.path.insert(0, str(ROOT))

from app.api.limits import describe_bytes, describe_slots
from app.config import Settings
from tests.hardening.live import stretched_bvh
from tests.hardening.test_busy import Crowd, health_watched

CAP_SHARE = 0.99


def at_the_cap(settings: Settings, count: int) -> list[tuple[str, bytes]]:
    source = shared_data() / "cmu" / "bvh-mb" / "01" / "01_01.bvh"
    text = source.read_text()
    columns = 96  # the file's channels; 38 joints with end sites: 9 x 38 = 342 per frame
    frames = int(CAP_SHARE * settings.max_frame_values / max(columns, 9 * 38))
    return [(f"cap_{n}.bvh", stretched_bvh(frames, 500 + n, text)) for n in range(count)]


def large_takes(count: int) -> list[tuple[str, bytes]]:
    takes = sorted((shared_data() / "cmu" / "bvh-mb").rglob("*.bvh"))
    takes = [path for path in takes if path.stat().st_size > 2_000_000]
    files = []
    for n in range(count):
        path = takes[n % len(takes)]
        data = path.read_bytes() + b"\n" * (1 + n // len(takes) + int(time.time()) % 1000)
        files.append((f"{path.stem}_{n}.bvh", data))
    return files


def crowd_round(server: Server, files: list[tuple[str, bytes]]) -> dict[str, object]:
    baseline = rss_bytes(server.process.pid)
    peak = baseline
    stop = threading.Event()

    def sample() -> None:
        nonlocal peak
        while not stop.wait(0.05):
            peak = max(peak, rss_bytes(server.process.pid))

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    answers: Counter[object] = Counter()
    retry_after: set[str] = set()
    crowd = Crowd()
    start = threading.Barrier(len(files))

    def send(name: str, data: bytes) -> None:
        start.wait()
        try:
            with httpx.Client(base_url=server.base, timeout=600) as client:
                response = client.post("/clips", files={"file": (name, data)})
        except httpx.HTTPError as error:
            answers[type(error).__name__] += 1
            return
        answers[response.status_code] += 1
        if response.status_code == 503:
            retry_after.add(response.headers.get("retry-after", "missing"))

    began = time.perf_counter()
    with health_watched(server.base, crowd):
        time.sleep(0.5)
        threads = [threading.Thread(target=send, args=file) for file in files]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    stop.set()
    sampler.join()
    return {
        "seconds": round(time.perf_counter() - began, 1),
        "answers": dict(answers),
        "retry_after": sorted(retry_after),
        "health_slowest_s": round(max(crowd.health, default=float("nan")), 3),
        "health_count": len(crowd.health),
        "health_failures": len(crowd.health_failures),
        "rss_idle_mb": round(baseline / 2**20),
        "rss_growth_mb": round((peak - baseline) / 2**20),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--large", type=int, default=40)
    parser.add_argument("--at-cap", type=int, default=12)
    parser.add_argument("--slots", type=int, help="MOCAP_MAX_CONCURRENT_DESCRIBES (default 0)")
    args = parser.parse_args()
    extra = {"MOCAP_MAX_CONCURRENT_DESCRIBES": str(args.slots)} if args.slots else {}
    settings = Settings(**({"max_concurrent_describes": args.slots} if args.slots else {}))
    slots = describe_slots(settings)
    bound = slots * describe_bytes(settings)
    print(f"machine: {machine()}")
    print(
        f"describe slots (MOCAP_MAX_CONCURRENT_DESCRIBES=0: from the machine): {slots}; "
        f"bound {slots} x {describe_bytes(settings) / 2**20:.0f} MB = {bound / 2**20:.0f} MB"
    )
    ok = True
    with tempfile.TemporaryDirectory(prefix="mocap-bench-busy-") as tmp:
        server = Server(Path(tmp) / "data", Path(tmp) / "server.log", **extra)
        try:
            for name, files in (
                (f"{args.large} large real takes", large_takes(args.large)),
                (f"{args.at_cap} at the frame-values cap", at_the_cap(settings, args.at_cap)),
            ):
                result = crowd_round(server, files)
                print(f"{name}: {result}")
                ok &= set(result["answers"]) <= {200, 201, 503}  # type: ignore[arg-type]
                ok &= result["health_slowest_s"] < 1.0 and not result["health_failures"]
                ok &= result["rss_growth_mb"] * 2**20 <= bound  # type: ignore[operator]
        finally:
            server.stop()
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
