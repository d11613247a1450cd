"""A ten-minute query take against a 10,000-clip library at the largest ``k`` (issue 21).

Run from the repository root::

    .venv/bin/python bench/bench_long_query.py [--clips 10000] [--minutes 10] [--data-dir DIR]

The library (cached in ``DIR``, default ``$TMPDIR/mocap-bench-long-query-<clips>``): Bandai
dataset 1 imported, then ``mocap-index fill-synthetic`` clips (noisy copies of the real ones,
with their windows) up to ``--clips``. The query: a real take of ``--minutes`` built by
joining Bandai clips of one hierarchy end to end (``bench_moments.build_take``: each clip's
root moved to where the previous one ended), again and again until it is long enough.

Against a real server with the default settings, each case runs once while the server's RSS
(all its processes) is sampled every 20 ms:

* ``POST /search/moments`` with the take, ``k`` = ``MOCAP_MAX_K``, ``per_clip`` = 1000;
* ``GET /search/moments?clip=<the take, stored>`` over the whole take, same ``k``.

Targets: an answer (200) or a clean 422 within 10 s, RSS growth over the idle server at most
500 MB. A case whose RSS grows past ``--kill-at-gb`` is stopped (the server killed) and
reported as such: the machines here are shared.
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx
from bench_moments import _bvh_parts, build_take
from bench_search import CLI, Server, environment, rss_bytes
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

TARGET_SECONDS = 10.0
TARGET_GROWTH = 500 * 2**20
PER_CLIP = 1000


def ensure_library(data_dir: Path, clips: int, sources: list[str]) -> None:
    database = data_dir / "mocap-index.sqlite3"
    if not database.exists():
        for source in sources:
            folder = str(shared_data() / source)
            command = [CLI, "import", "--no-progress", "--data-dir", str(data_dir), folder]
            subprocess.run(command, check=True, env=environment())
    with sqlite3.connect(database) as db:
        held = db.execute("SELECT count(*) FROM clips").fetchone()[0]
    if held < clips:
        command = [CLI, "fill-synthetic", "--count", str(clips), "--data-dir", str(data_dir)]
        subprocess.run(command, check=True, env=environment())


def library_size(data_dir: Path) -> str:
    """Clips, hours and windows per length, as the library holds them."""
    with sqlite3.connect(data_dir / "mocap-index.sqlite3") as db:
        clips, hours = db.execute(
            "SELECT count(*), sum(frame_count * frame_time) / 3600 FROM clips"
        ).fetchone()
        windows = db.execute(
            "SELECT length, count(*) FROM clip_windows GROUP BY length ORDER BY length"
        ).fetchall()
    shown = ", ".join(f"{count:,} of {length:g} s" for length, count in windows)
    return f"{clips:,} clips, {hours:.0f} h; windows: {shown}"


def long_take(minutes: float) -> tuple[bytes, float]:
    """A real take of at least ``minutes``: Bandai clips of the commonest hierarchy, joined."""
    paths = sorted((shared_data() / "bandai-ds1").rglob("*.bvh"))
    headers = {path: _bvh_parts(path.read_text())[0] for path in paths}
    common, _ = Counter(headers.values()).most_common(1)[0]
    same = [path for path in paths if headers[path] == common]
    chosen: list[Path] = []
    seconds = 0.0
    while seconds < minutes * 60:
        for path in same:
            _, lines, frame_time = _bvh_parts(path.read_text())
            chosen.append(path)
            seconds += len(lines) * float(frame_time.split(":")[1])
            if seconds >= minutes * 60:
                break
    text, _ = build_take(chosen)
    return text.encode(), seconds


class Watched:
    """The server's peak RSS while a request runs (sampled every 20 ms); kills the server
    when it grows past ``kill_at`` bytes over ``baseline``."""

    def __init__(self, server: Server, baseline: int, kill_at: int) -> None:
        self.server, self.baseline, self.kill_at = server, baseline, kill_at
        self.peak = baseline
        self.killed = False
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _sample(self) -> None:
        while not self._stop.is_set():
            rss = rss_bytes(self.server.process.pid)
            self.peak = max(self.peak, rss)
            if rss - self.baseline > self.kill_at:
                self.killed = True
                self.server.process.kill()
                return
            self._stop.wait(0.02)

    def __enter__(self) -> Watched:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def run_case(
    name: str, server: Server, kill_at: int, request: dict[str, object]
) -> dict[str, object]:
    baseline = rss_bytes(server.process.pid)
    started = time.perf_counter()
    status: object = None
    with Watched(server, baseline, kill_at) as watched:
        try:
            with httpx.Client(base_url=server.base, timeout=600) as client:
                response = client.request(**request)  # type: ignore[arg-type]
            status = response.status_code
            detail = response.json().get("detail", "") if status != 200 else ""
            count = len(response.json().get("results", [])) if status == 200 else 0
        except httpx.HTTPError as error:
            status, detail, count = f"no answer ({type(error).__name__})", "", 0
    seconds = time.perf_counter() - started
    growth = watched.peak - baseline
    result = {
        "case": name,
        "status": status,
        "seconds": round(seconds, 2),
        "moments": count,
        "rss_idle_mb": round(baseline / 2**20),
        "rss_growth_mb": round(growth / 2**20),
        "killed": watched.killed,
        "detail": detail[:200],
    }
    ok = status in (200, 422) and seconds <= TARGET_SECONDS and growth <= TARGET_GROWTH
    print(
        f"{name}: {status} in {seconds:.2f} s, {count} moments; RSS {baseline / 2**20:.0f} MB "
        f"idle, +{growth / 2**20:.0f} MB at peak"
        + (" (killed: past the limit)" if watched.killed else "")
        + ("" if ok else "  <-- over target")
        + (f"; {detail[:160]}" if detail else "")
    )
    result["ok"] = ok
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--clips", type=int, default=10_000)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--data-dir", type=Path)
    parser.add_argument("--kill-at-gb", type=float, default=4.0)
    parser.add_argument(
        "--source",
        action="append",
        help="folder of ../shared/data imported before the synthetic fill (repeatable; "
        "default bandai-ds1: short clips; cmu: takes of 1-43 s, eight times the windows)",
    )
    args = parser.parse_args()
    sources = args.source or ["bandai-ds1"]
    data_dir = args.data_dir or Path(tempfile.gettempdir()) / (
        f"mocap-bench-long-query-{'-'.join(s.replace('/', '_') for s in sources)}-{args.clips}"
    )
    print(f"machine: {machine()}")
    ensure_library(data_dir, args.clips, sources)
    take, seconds = long_take(args.minutes)
    print(f"library: {data_dir} ({library_size(data_dir)}); take: {seconds / 60:.1f} min")
    log = data_dir.parent / "mocap-bench-long-query-server.log"
    kill_at = int(args.kill_at_gb * 2**30)
    server = Server(data_dir, log)
    results = []
    try:
        with httpx.Client(base_url=server.base, timeout=120) as client:
            max_k = 1000  # MOCAP_MAX_K's default: the server runs with the defaults
            # warm: places, indexes and code paths the cases use
            client.get("/search/moments", params={"clip": 1, "k": 10})
            stored = client.post("/clips", files={"file": ("take.bvh", take)})
            stored.raise_for_status()
            take_id = stored.json()["id"]
        params = {"k": max_k, "per_clip": PER_CLIP}
        results.append(
            run_case(
                "POST /search/moments (the take uploaded)",
                server,
                kill_at,
                {
                    "method": "POST",
                    "url": "/search/moments",
                    "params": params,
                    "files": {"file": ("take.bvh", take)},
                },
            )
        )
        if server.process.poll() is None:
            results.append(
                run_case(
                    "GET /search/moments (the take stored, whole span)",
                    server,
                    kill_at,
                    {
                        "method": "GET",
                        "url": "/search/moments",
                        "params": {**params, "clip": take_id},
                    },
                )
            )
    finally:
        if server.process.poll() is None:
            server.stop()
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    return 0 if all(r["ok"] for r in results) and len(results) == 2 else 1


if __name__ == "__main__":
    sys.exit(main())
