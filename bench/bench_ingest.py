"""Bulk import benchmark: ``mocap-index import`` of Bandai dataset 1 into a fresh data dir.

Run from the repository root::

    .venv/bin/python bench/bench_ingest.py [--repeat 5] [--workers N] [--data PATH]

Each run starts the real command in a new process on an empty temporary data directory and
times it end to end (process start to exit: parse, kinematics, every descriptor, database,
indexes, with the default settings). It then checks the library holds every clip, once, with
its vectors in every index, and that a second run skips everything. Target: at most 2.5 s.
The data folder is ``../shared/data`` or ``$MOCAP_SHARED_DATA``.

``--clips N`` imports a library of N Bandai-sized clips instead: copies of the dataset's
files, copy ``i`` with ``i`` extra trailing newlines so every file is new content (target:
at least 250 clips/s for 3,000 clips, issue 13).

``--synchronous FULL,NORMAL`` runs the import under each ``MOCAP_SQLITE_SYNCHRONOUS`` in turn
(interleaved, so both see the same load) and prints each median and their ratio: what the
durable default costs (issue 21).
"""

from __future__ import annotations

import argparse
import json
import os
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import machine, shared_data  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
TARGET_SECONDS = 2.5
TARGET_CLIPS_PER_SECOND = 250


def run_import(
    data_dir: Path, source: Path, workers: int | None, synchronous: str | None = None
) -> tuple[float, str]:
    command = [str(ROOT / ".venv" / "bin" / "mocap-index"), "import", "--no-progress"]
    if workers:
        command += ["--workers", str(workers)]
    command += ["--data-dir", str(data_dir), str(source)]
    env = {k: v for k, v in os.environ.items() if not k.startswith("MOCAP_")}
    if synchronous:
        env["MOCAP_SQLITE_SYNCHRONOUS"] = synchronous
    started = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        raise SystemExit(f"import failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return seconds, done.stdout.strip().splitlines()[-1]


def check(data_dir: Path, expected: int) -> None:
    db = sqlite3.connect(data_dir / "mocap-index.sqlite3")
    clips, hashes = db.execute(
        "SELECT count(*), count(DISTINCT content_hash) FROM clips"
    ).fetchone()
    names = [r[0] for r in db.execute("SELECT DISTINCT name FROM clip_descriptors")]
    db.close()
    assert clips == hashes == expected, (clips, hashes, expected)
    for name in names:
        meta = json.loads((data_dir / "indexes" / f"{name}.json").read_text())
        assert meta["count"] == expected, (name, meta)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--workers", type=int, help="default: the command's default")
    parser.add_argument("--data", type=Path, help="default: <shared data>/bandai-ds1")
    parser.add_argument("--clips", type=int, help="import this many copies of the files")
    parser.add_argument(
        "--synchronous",
        help="comma-separated MOCAP_SQLITE_SYNCHRONOUS modes to compare (e.g. FULL,NORMAL)",
    )
    args = parser.parse_args()
    source = args.data or shared_data() / "bandai-ds1"
    if args.clips:
        with tempfile.TemporaryDirectory(prefix="mocap-bench-copies-") as copies:
            return run(args, copied(source, Path(copies), args.clips))
    return run(args, source)


def copied(source: Path, target: Path, count: int) -> Path:
    """``count`` BVH files in ``target``: the files of ``source`` again and again, copy ``i``
    with ``i`` more trailing newlines (new content, same motion)."""
    originals = sorted(source.rglob("*.bvh"))
    for number in range(count):
        path = originals[number % len(originals)]
        copy = number // len(originals)
        data = path.read_bytes() + b"\n" * copy
        (target / f"{path.stem}_copy{copy:03d}.bvh").write_bytes(data)
    return target


def run(args: argparse.Namespace, source: Path) -> int:
    files = sorted(source.rglob("*.bvh"))
    if not files:
        print(f"no BVH files under {source}", file=sys.stderr)
        return 2
    size = sum(f.stat().st_size for f in files)
    print(f"machine: {machine()}")
    print(f"data: {source} ({len(files)} BVH, {size / 1e6:.1f} MB)")
    modes = args.synchronous.split(",") if args.synchronous else [None]
    runs: dict[str | None, list[float]] = {mode: [] for mode in modes}
    for attempt in range(1, args.repeat + 1):
        for mode in modes:
            with tempfile.TemporaryDirectory(prefix="mocap-bench-ingest-") as tmp:
                data_dir = Path(tmp) / "data"
                seconds, summary = run_import(data_dir, source, args.workers, mode)
                check(data_dir, len(files))
                again, summary_again = run_import(data_dir, source, args.workers, mode)
                assert f"skipped {len(files)} as duplicates" in summary_again, summary_again
                check(data_dir, len(files))
            runs[mode].append(seconds)
            named = f" synchronous={mode}" if mode else ""
            print(f"run {attempt}{named}: {seconds:.2f} s wall ({summary}); re-run {again:.2f} s")
    if len(modes) > 1:
        medians = {mode: statistics.median(times) for mode, times in runs.items()}
        base = medians[modes[0]]
        for mode, median in medians.items():
            print(
                f"synchronous={mode}: median {median:.2f} s "
                f"({len(files) / median:.0f} clips/s), {median / base:.2f} x {modes[0]}"
            )
    times = runs[modes[0]]
    median = statistics.median(times)
    print(
        f"import of {len(files)} clips: best {min(times):.2f} s, median "
        f"{median:.2f} s, worst {max(times):.2f} s ({len(files) / median:.0f} clips/s; target "
        f"{TARGET_SECONDS} s for bandai-ds1, 250 clips/s for 3,000 clips)"
    )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if args.clips:
        return 0 if len(files) / median >= TARGET_CLIPS_PER_SECOND else 1
    return 0 if median <= TARGET_SECONDS else 1


if __name__ == "__main__":
    sys.exit(main())
