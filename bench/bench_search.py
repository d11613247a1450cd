"""Search at scale: ``GET /search?clip=..&k=10`` with a library of 1,000,000 clips.

Run from the repository root (``wrk`` must be installed: ``apt-get install -y wrk``)::

    .venv/bin/python bench/bench_search.py [--data-dir DIR] [--count 1000000] [--duration 20]

The library runs with ``MOCAP_MOMENTS=false`` (import, fill and server): a million clips of a
few seconds are well over 1,000 hours, whose moment windows (about 1 GB per 100 hours in every
server process) this whole-clip benchmark does not measure. ``--descriptor`` (default
``motion``, the service's default) is the one searched under load and checked over HTTP.

1. Fill: when ``DIR`` (default ``$TMPDIR/mocap-bench-1m``) holds fewer than ``--count``
   clips, import the Bandai dataset 1 (real clips, if ``../shared/data`` has it) and run
   ``mocap-index fill-synthetic --count N`` (about 3 minutes for a million here).
2. Recall: open the library in this process and measure recall@10 of every descriptor's index
   against exact search (``IndexFlatL2`` over the same vectors) for 1,000 random stored clips,
   excluding the query clip as the service does; for ``--descriptor`` also at other ``nprobe``.
3. Start-up: start ``mocap-index serve`` (``MOCAP_LOG_LEVEL=warning``: no access log) three
   times and time each until ``/health`` answers 200 (indexes loaded, not rebuilt).
4. Load: ``wrk`` with ``bench/search.lua`` (random clip ids, every response checked: status
   200 and 10 hits) at 1 connection and at 32, ``--duration`` seconds each after a warm-up;
   median/p99 latency and requests/s. The server's resident memory (VmRSS, the server and any
   child processes summed) is sampled every 0.2 s throughout; the peak is reported.
5. Correctness: 300 searches over HTTP after the load, each checked against exact search:
   the distances are the true Euclidean distances of the returned clips' stored vectors,
   ascending, the query clip absent, and the overlap with the exact top 10 (recall) reported.
   The exact top 10 are found from float32 dot products, then the 50 nearest re-ranked in
   float64.

``--baseline CHECKOUT`` (e.g. ``/work/main``, with its own ``.venv``) also serves the library
with that checkout's ``mocap-index`` and measures it in the same rounds, right after this
checkout's server: a change's effect is then a ratio of one run, not of two runs on a machine
whose speed moves. ``--baseline-data-dir`` gives it a copy of the library instead, for
checkouts whose index files differ (each server would rebuild the other's at start).

Targets (issue 23, the ones the script checks): >= 50 % of the floor's requests/s at 32
connections, median <= 0.6 ms at 1 connection, recall@10 >= 0.99, RSS <= 1.5 GB, start-up
<= 5 s. Loopback only; every loop is bounded in time.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import re
import shutil
import signal
import socket
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CLI = str(ROOT / ".venv" / "bin" / "mocap-index")
LUA = ROOT / "bench" / "search.lua"


def environment(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    env.update(extra)
    return env


NO_MOMENTS = {"MOCAP_MOMENTS": "false"}  # see the module docstring


def clip_count(data_dir: Path) -> int:
    path = data_dir / "mocap-index.sqlite3"
    if not path.exists():
        return 0
    db = sqlite3.connect(path)
    try:
        return int(db.execute("SELECT count(*) FROM clips").fetchone()[0])
    except sqlite3.OperationalError:
        return 0
    finally:
        db.close()


def fill(data_dir: Path, count: int) -> None:
    if clip_count(data_dir) >= count:
        print(f"library: {data_dir} already holds {clip_count(data_dir)} clips")
        return
    started = time.perf_counter()
    bandai = shared_data() / "bandai-ds1"
    if bandai.is_dir() and clip_count(data_dir) == 0:
        subprocess.run(
            [CLI, "import", "--no-progress", "--data-dir", str(data_dir), str(bandai)],
            check=True,
            env=environment(**NO_MOMENTS),
        )
    subprocess.run(
        [CLI, "fill-synthetic", "--count", str(count), "--data-dir", str(data_dir)],
        check=True,
        env=environment(**NO_MOMENTS),
    )
    print(f"library filled to {count} clips in {time.perf_counter() - started:.0f} s")


def recall(data_dir: Path, queries: int, seed: int, descriptor: str) -> dict[str, float]:
    """recall@10 of each descriptor's index against exact search, in this process."""
    import faiss

    from app.config import Settings
    from app.services.library import open_library

    library = open_library(Settings(data_dir=data_dir, moments=False))
    results: dict[str, float] = {}
    try:
        rng = np.random.default_rng(seed)
        for name, index in library.indexes.items():
            ids, vectors = index.all_vectors()
            order = np.argsort(ids)
            ids, vectors = ids[order], vectors[order]
            rows = rng.choice(ids.size, size=min(queries, ids.size), replace=False)
            exact = faiss.IndexFlatL2(vectors.shape[1])
            exact.add(vectors)
            faiss.omp_set_num_threads(os.cpu_count() or 1)
            _, truth = exact.search(vectors[rows], 11)
            faiss.omp_set_num_threads(1)
            del exact
            default = index.nprobe
            nprobes = [default]
            if name == descriptor and index.kind == "ivf":
                nprobes = sorted({4, 8, 16, 32, 64, default})
            options = index.options
            for nprobe in nprobes:
                index.options = dataclasses.replace(options, nprobe=nprobe)
                found = hits = 0
                started = time.perf_counter()
                for row, true_rows in zip(rows, truth, strict=True):
                    want = [int(ids[r]) for r in true_rows if r != row][:10]
                    got = index.search(vectors[row], 10, exclude=int(ids[row])).ids.tolist()
                    found += len(set(want) & set(got))
                    hits += len(want)
                per_query = (time.perf_counter() - started) / len(rows) * 1e6
                print(
                    f"recall@10 {name:8s} ({index.kind}, {index.size} vectors, nprobe "
                    f"{nprobe:3d}{'*' if nprobe == default else ' '}): {found / hits:.4f}  "
                    f"({per_query:.0f} us per query)"
                )
                if nprobe == default:
                    results[name] = found / hits
            index.options = options
            del vectors
    finally:
        library.close()
    return results


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def family(pid: int) -> list[int]:
    """``pid`` and its descendants."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    found, todo = [], [pid]
    while todo:
        current = todo.pop()
        found.append(current)
        todo.extend(children.get(current, []))
    return found


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system) used so far by ``pid`` and its descendants."""
    ticks = os.sysconf("SC_CLK_TCK")
    total = 0
    for member in family(pid):
        try:
            fields = Path(f"/proc/{member}/stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / ticks


def timed_wrk(
    server: Server, connections: int, seconds: int, max_id: int, **options: str
) -> dict[str, float]:
    """:func:`wrk`, plus ``cpu_ms``: the server's CPU time per request (all its processes).
    On a shared machine requests/s depend on what the others run; CPU per request much
    less."""
    before = cpu_seconds(server.process.pid)
    result = wrk(server.base, connections, seconds, max_id, **options)
    used = cpu_seconds(server.process.pid) - before
    result["cpu_ms"] = 1000 * used / max(result["requests"], 1)
    return result


def pss_bytes(pid: int) -> int:
    """Proportional set size of ``pid`` and its descendants: each page shared by n processes
    (a memory-mapped index file, a forked worker's pages) counted 1/n in each, so the sum is
    the memory they take together. VmRSS counts a shared page in full in every process."""
    total = 0
    for member in family(pid):
        try:
            for line in Path(f"/proc/{member}/smaps_rollup").read_text().splitlines():
                if line.startswith("Pss:"):
                    total += int(line.split()[1]) * 1024
        except OSError:
            continue
    return total


def rss_bytes(pid: int) -> int:
    total = 0
    for member in family(pid):
        try:
            for line in Path(f"/proc/{member}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1]) * 1024
        except OSError:
            continue
    return total


class Server:
    """``mocap-index serve`` on a free port (``settings``: ``MOCAP_*`` variables), started and
    timed until ``/health`` answers."""

    def __init__(self, data_dir: Path, log: Path, **settings: str) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.started = time.perf_counter()
        with open(log, "ab") as out:
            self.process = self.launch(data_dir, out, settings)
        deadline = time.monotonic() + 120
        while True:
            if self.process.poll() is not None:
                raise SystemExit(f"server exited early, see {log}")
            try:
                if httpx.get(f"{self.base}/health", timeout=10).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                self.stop()
                raise SystemExit("server did not start within 120 s")
            time.sleep(0.05)
        self.startup = time.perf_counter() - self.started
        # The CPU the start took, all processes: on a shared machine the wall time above is
        # mostly waiting for a core.
        self.startup_cpu = cpu_seconds(self.process.pid)
        self.peak_rss = 0
        self.peak_pss = 0
        self._sampling = threading.Event()
        self._sampler = threading.Thread(target=self._sample, daemon=True)
        self._sampler.start()

    cli = CLI  # the mocap-index serving (Baseline: another checkout's)
    checkout = ROOT  # ... and the code it serves

    def launch(self, data_dir: Path, out: Any, settings: dict[str, str]) -> subprocess.Popen[bytes]:
        command = [self.cli, "serve", "--data-dir", str(data_dir), "--port", str(self.port)]
        # The checkout's own code first on the path: a .venv may be an editable install of
        # another checkout (two worktrees sharing one environment).
        env = environment(MOCAP_LOG_LEVEL="warning", PYTHONPATH=str(self.checkout), **settings)
        return subprocess.Popen(command, env=env, stdout=out, stderr=out)

    def _sample(self) -> None:
        while not self._sampling.is_set():
            self.peak_rss = max(self.peak_rss, rss_bytes(self.process.pid))
            self.peak_pss = max(self.peak_pss, pss_bytes(self.process.pid))
            self._sampling.wait(0.2)

    def stop(self) -> None:
        if hasattr(self, "_sampling"):
            self._sampling.set()
        self.process.send_signal(signal.SIGINT)
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


def baseline_server(checkout: Path, data_dir: Path, log: Path, **settings: str) -> Server:
    """``mocap-index serve`` of another checkout (``--baseline``, e.g. main's, with its own
    ``.venv``) on the same library: measured in the same rounds as this checkout's."""

    class Baseline(Server):
        cli = str(checkout / ".venv" / "bin" / "mocap-index")

    Baseline.checkout = checkout

    return Baseline(data_dir, log, **settings)


class Floor(Server):
    """The HTTP floor (``bench/floor_app.py``) with the uvicorn settings of ``mocap-index
    serve``: one process, or ``MOCAP_WORKERS`` of them."""

    def launch(self, data_dir: Path, out: Any, settings: dict[str, str]) -> subprocess.Popen[bytes]:
        workers = settings.get("MOCAP_WORKERS", "1")
        command = [
            str(ROOT / ".venv" / "bin" / "uvicorn"),
            "floor_app:create_floor_app",
            "--factory",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--log-level",
            "warning",
        ]
        if workers != "1":
            command += ["--workers", workers]
        env = environment(PYTHONPATH=str(ROOT / "bench"))
        return subprocess.Popen(command, env=env, stdout=out, stderr=out, cwd=ROOT / "bench")


def wrk(
    base: str,
    connections: int,
    seconds: int,
    max_id: int,
    *,
    path: str = "/search",
    descriptor: str = "posture",
) -> dict[str, float]:
    threads = 1 if connections == 1 else 2
    command = [
        "wrk",
        f"-t{threads}",
        f"-c{connections}",
        f"-d{seconds}s",
        "--timeout",
        "10s",
        "-s",
        str(LUA),
        base,
    ]
    env = environment(
        MOCAP_BENCH_MAX_ID=str(max_id), MOCAP_BENCH_DESCRIPTOR=descriptor, MOCAP_BENCH_PATH=path
    )
    done = subprocess.run(command, env=env, capture_output=True, text=True, timeout=seconds + 60)
    match = re.search(r"^RESULT (.*)$", done.stdout, flags=re.MULTILINE)
    if match is None:
        raise SystemExit(f"wrk failed:\n{done.stdout}\n{done.stderr}")
    return {k: float(v) for k, v in (pair.split("=") for pair in match.group(1).split())}


def check_answers(base: str, data_dir: Path, samples: int, seed: int, descriptor: str) -> float:
    """Searches over HTTP checked against the stored vectors; returns recall@10."""
    db = sqlite3.connect(data_dir / "mocap-index.sqlite3")
    max_id = int(db.execute("SELECT max(id) FROM clips").fetchone()[0])
    rows = db.execute(
        "SELECT clip_id, vector FROM clip_descriptors WHERE name = ? ORDER BY clip_id",
        (descriptor,),
    ).fetchall()
    ids = np.fromiter((r[0] for r in rows), np.int64, len(rows))
    vectors = np.frombuffer(b"".join(r[1] for r in rows), "<f4").reshape(ids.size, -1)
    del rows
    db.close()
    squared = np.einsum("ij,ij->i", vectors, vectors)
    rng = np.random.default_rng(seed)
    found = wanted = 0
    with httpx.Client(base_url=base, timeout=30) as client:
        for clip in rng.integers(1, max_id + 1, samples):
            answer = client.get(
                "/search", params={"clip": int(clip), "k": 10, "descriptor": descriptor}
            ).json()
            hits = answer["results"]
            assert answer["query"]["id"] == clip and len(hits) == 10, answer
            row = int(np.searchsorted(ids, clip))
            query = vectors[row].astype(np.float64)
            got = [h["id"] for h in hits]
            assert int(clip) not in got
            distances = [h["distance"] for h in hits]
            assert distances == sorted(distances)
            true = np.linalg.norm(
                vectors[np.searchsorted(ids, got)].astype(np.float64) - query, axis=1
            )
            np.testing.assert_allclose(distances, true, rtol=1e-4, atol=1e-6)
            rough = squared - 2 * (vectors @ vectors[row])
            rough[row] = np.inf
            near = np.argpartition(rough, 50)[:50]
            exact = np.linalg.norm(vectors[near].astype(np.float64) - query, axis=1)
            best = ids[near[np.lexsort((ids[near], exact))][:10]]
            found += len(set(best.tolist()) & set(got))
            wanted += 10
    return found / wanted


def load_runs(
    service: Server,
    floor: Server,
    clips: int,
    descriptors: list[str],
    *,
    duration: int,
    rounds: int,
    baseline: Server | None = None,
) -> tuple[dict[int, list[dict[str, float]]], dict[tuple[int, str, str], list[dict[str, float]]]]:
    """``rounds`` rounds at 1 and at 32 connections, each the floor then every descriptor in
    turn (so a slow spell of the shared machine hits both), the ``baseline`` checkout's
    server right after this one's: the floor's results by connections, the servers' by
    (connections, descriptor, ``"service"`` or ``"baseline"``)."""
    servers = (
        {"service": service} if baseline is None else {"service": service, "baseline": baseline}
    )
    floors: dict[int, list[dict[str, float]]] = {}
    searches: dict[tuple[int, str, str], list[dict[str, float]]] = {}
    wrk(floor.base, 32, 3, clips)  # warm-up
    for descriptor in descriptors:
        for server in servers.values():
            wrk(server.base, 32, 3, clips, descriptor=descriptor)
    for connections in (1, 32):
        for _ in range(rounds):
            result = timed_wrk(floor, connections, duration, clips)
            floors.setdefault(connections, []).append(result)
            print(f"  floor         {connections:2d} conn: {summary(result)}")
            for descriptor in descriptors:
                for role, server in servers.items():
                    result = timed_wrk(server, connections, duration, clips, descriptor=descriptor)
                    searches.setdefault((connections, descriptor, role), []).append(result)
                    name = descriptor if role == "service" else f"{descriptor} (base)"
                    print(f"  {name:15s} {connections:2d} conn: {summary(result)}")
    return floors, searches


def summary(result: dict[str, float]) -> str:
    return (
        f"{result['rps']:7.0f} requests/s, median {result['p50_ms']:.2f} ms, "
        f"p99 {result['p99_ms']:.2f} ms, server CPU {result['cpu_ms']:.3f} ms/request, "
        f"{int(result['bad'])} bad, {int(result['errors'])} errors"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--data-dir", type=Path, default=Path(tempfile.gettempdir()) / "mocap-bench-1m"
    )
    parser.add_argument("--count", type=int, default=1_000_000)
    parser.add_argument("--duration", type=int, default=10, help="seconds per wrk run")
    parser.add_argument("--rounds", type=int, default=2, help="wrk runs of each, interleaved")
    parser.add_argument("--queries", type=int, default=1000, help="recall queries")
    parser.add_argument("--skip-recall", action="store_true")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--descriptors", default="motion,posture,kinetic", help="searched under load"
    )
    parser.add_argument("--workers", type=int, default=1, help="server processes")
    parser.add_argument(
        "--baseline",
        type=Path,
        help="another checkout (with its .venv) whose server is measured in the same rounds",
    )
    parser.add_argument(
        "--baseline-data-dir",
        type=Path,
        help="a copy of the library for --baseline to serve (default: --data-dir): needed "
        "when the two checkouts' index files differ (e.g. MOCAP_CLIP_CODES), or each server "
        "would rebuild the other's",
    )
    args = parser.parse_args()
    if shutil.which("wrk") is None:
        print("wrk is not installed (apt-get install -y wrk)", file=sys.stderr)
        return 2
    descriptors = args.descriptors.split(",")
    print(f"machine: {machine()}")
    fill(args.data_dir, args.count)
    clips = clip_count(args.data_dir)
    failures = []
    if not args.skip_recall:
        recalls = recall(args.data_dir, args.queries, args.seed, descriptors[0])
        failures += [f"recall {d}" for d in descriptors if recalls.get(d, 1.0) < 0.99]
    log = args.data_dir / "bench-server.log"
    settings = {**NO_MOMENTS, "MOCAP_WORKERS": str(args.workers)}
    startups, startup_cpu = [], []
    for _ in range(2):
        server = Server(args.data_dir, log, **settings)
        startups.append(server.startup)
        startup_cpu.append(server.startup_cpu)
        server.stop()
    server = Server(args.data_dir, log, **settings)
    startups.append(server.startup)
    startup_cpu.append(server.startup_cpu)
    print(
        f"start-up with {clips} clips, {args.workers} worker(s): "
        f"{', '.join(f'{s:.2f}' for s in startups)} s (median {statistics.median(startups):.2f}); "
        f"CPU {', '.join(f'{s:.2f}' for s in startup_cpu)} s"
    )
    floor = Floor(args.data_dir, log, MOCAP_WORKERS=str(args.workers))
    baseline = None
    if args.baseline is not None:
        baseline_data = args.baseline_data_dir or args.data_dir
        baseline = baseline_server(args.baseline, baseline_data, log, **settings)
        print(
            f"baseline {args.baseline}: started in {baseline.startup:.2f} s, "
            f"CPU {baseline.startup_cpu:.2f} s"
        )
    try:
        print(f"load average before the load: {os.getloadavg()[0]:.2f}")
        floors, searches = load_runs(
            server,
            floor,
            clips,
            descriptors,
            duration=args.duration,
            rounds=args.rounds,
            baseline=baseline,
        )
        load_after = os.getloadavg()[0]
        http_recall = check_answers(server.base, args.data_dir, 300, args.seed, descriptors[0])
        print(
            f"300 {descriptors[0]} answers checked against exact search: all correct, "
            f"recall@10 {http_recall:.4f}"
        )
        print(
            f"server memory, peak: VmRSS {server.peak_rss / 2**30:.2f} GiB summed over its "
            f"processes, PSS {server.peak_pss / 2**30:.2f} GiB"
        )
    finally:
        floor.stop()
        server.stop()
        if baseline is not None:
            baseline.stop()
    print(f"load average after the load: {load_after:.2f}")
    floor_rps = {c: statistics.median(r["rps"] for r in runs) for c, runs in floors.items()}
    floor_p50 = {c: statistics.median(r["p50_ms"] for r in runs) for c, runs in floors.items()}
    print(
        f"floor: {floor_rps[32]:.0f} requests/s at 32 connections, median "
        f"{floor_p50[1]:.2f} ms at 1"
    )
    floor_cpu = statistics.median(r["cpu_ms"] for r in floors[32])
    for descriptor in descriptors:
        if baseline is not None:
            base_rps = statistics.median(r["rps"] for r in searches[(32, descriptor, "baseline")])
            base_p50 = statistics.median(r["p50_ms"] for r in searches[(1, descriptor, "baseline")])
            base_cpu = statistics.median(
                r["cpu_ms"] for r in searches[(32, descriptor, "baseline")]
            )
            print(
                f"{descriptor} (baseline {args.baseline}): {base_rps:.0f} requests/s at 32 "
                f"connections = {base_rps / floor_rps[32]:.0%} of the floor, median "
                f"{base_p50:.2f} ms at 1; server CPU {base_cpu:.3f} ms per request"
            )
        rps = statistics.median(r["rps"] for r in searches[(32, descriptor, "service")])
        p50 = statistics.median(r["p50_ms"] for r in searches[(1, descriptor, "service")])
        cpu = statistics.median(r["cpu_ms"] for r in searches[(32, descriptor, "service")])
        ratio = rps / floor_rps[32]
        print(
            f"{descriptor}: {rps:.0f} requests/s at 32 connections = {ratio:.0%} of the floor "
            f"(target 50 %), median {p50:.2f} ms at 1 (target 0.6); server CPU "
            f"{cpu:.3f} ms per request, floor {floor_cpu:.3f} ({floor_cpu / cpu:.0%})"
        )
        if ratio < 0.5:
            failures.append(f"throughput {descriptor}")
        if p50 > 0.6:
            failures.append(f"median latency {descriptor}")
        if any(r["bad"] or r["errors"] for runs in searches.values() for r in runs):
            failures.append("answers")
    if server.peak_rss > 1.5 * 2**30 and server.peak_pss > 1.5 * 2**30:
        failures.append("memory")
    if statistics.median(startups) > 5:
        failures.append("start-up")
    print("targets met" if not failures else f"targets missed: {', '.join(failures)}")
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
