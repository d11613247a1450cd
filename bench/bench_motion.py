"""Time parse + forward kinematics + descriptors, single process, on Bandai dataset 1.

Run: ``.venv/bin/python bench/bench_motion.py [SHARED_DATA_DIR] [--repeat N]``

``--baseline CHECKOUT`` (another checkout with its own ``.venv``, e.g. main's) compares the
two instead: each round runs parse + FK + describe over every clip once in a fresh process
of each checkout, alternately, and reports the CPU time per clip (min and median over
``--rounds``) and their ratio. On a shared machine only such a same-session ratio means
anything.

Reports the mean time per clip over the 174 clips (files read into memory first, so disk
is not timed), the time for the largest file, and the split between parsing and analysis
(canonical mapping, lead-in detection, FK and every registered descriptor). Targets
(issue 2): at most 15 ms per average clip and 60 ms for the largest file.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

from app.motion.descriptors import REGISTRY
from app.motion.formats import read_bvh
from app.motion.pipeline import analyse


def _time(fn, repeat: int, clock=time.perf_counter) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeat):
        start = clock()
        fn()
        best = min(best, clock() - start)
    return best


# One measurement in a fresh process of a checkout: CPU ms per clip, best of 2 passes.
_ONE_ROUND = """
import sys, time
from pathlib import Path
from app.motion.formats import read_bvh
from app.motion.pipeline import analyse
blobs = [p.read_bytes() for p in sorted(Path(sys.argv[1]).glob("*.bvh"))]
for blob in blobs[:5]:
    analyse(read_bvh(blob))
best = float("inf")
for _ in range(2):
    start = time.process_time()
    for blob in blobs:
        analyse(read_bvh(blob))
    best = min(best, time.process_time() - start)
print(best / len(blobs) * 1000)
"""


def compare(baseline: Path, folder: Path, rounds: int) -> None:
    """CPU time per clip of this checkout and ``baseline``, alternating fresh processes."""
    here = Path(__file__).resolve().parents[1]
    times: dict[Path, list[float]] = {baseline: [], here: []}
    for _ in range(rounds):
        for checkout in (baseline, here):
            done = subprocess.run(
                [str(checkout / ".venv" / "bin" / "python"), "-c", _ONE_ROUND, str(folder)],
                cwd=checkout,
                capture_output=True,
                text=True,
                check=True,
            )
            times[checkout].append(float(done.stdout.strip().splitlines()[-1]))
    print(f"load average {os.getloadavg()[0]:.2f} after {rounds} rounds")
    for checkout, values in times.items():
        print(
            f"{checkout}: CPU {min(values):.2f} ms per clip at best, "
            f"{statistics.median(values):.2f} median ({', '.join(f'{v:.2f}' for v in values)})"
        )
    ratio = statistics.median(times[here]) / statistics.median(times[baseline])
    best = min(times[here]) / min(times[baseline])
    print(f"this checkout / baseline: {ratio:.3f} (median), {best:.3f} (best)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    parser.add_argument("shared_data", nargs="?", type=Path, default=default)
    parser.add_argument("--repeat", type=int, default=3, help="best of N runs (default 3)")
    parser.add_argument("--baseline", type=Path, help="another checkout to compare with")
    parser.add_argument("--rounds", type=int, default=6, help="rounds of --baseline")
    args = parser.parse_args()
    if args.baseline is not None:
        compare(args.baseline.resolve(), args.shared_data / "bandai-ds1" / "data", args.rounds)
        return

    files = sorted((args.shared_data / "bandai-ds1" / "data").glob("*.bvh"))
    blobs = [f.read_bytes() for f in files]
    largest = max(range(len(files)), key=lambda i: len(blobs[i]))

    def parse_all() -> None:
        for blob in blobs:
            read_bvh(blob)

    def full_all() -> None:
        for blob in blobs:
            analyse(read_bvh(blob))

    parse_total = _time(parse_all, args.repeat)
    full_total = _time(full_all, args.repeat)
    # CPU seconds of this process: what the code costs, less moved by other processes on a
    # shared machine than the wall clock (compare two versions by this, in one session).
    full_cpu = _time(full_all, args.repeat, time.process_time)
    largest_parse = _time(lambda: read_bvh(blobs[largest]), args.repeat * 3)
    largest_full = _time(lambda: analyse(read_bvh(blobs[largest])), args.repeat * 3)
    sizes = [len(b) for b in blobs]
    machine = f"{platform.machine()} {platform.processor()}".strip()
    print(f"machine: {machine}, python {platform.python_version()}, load {os.getloadavg()[0]:.2f}")
    print(f"descriptors: {', '.join(REGISTRY)}")
    print(f"{len(files)} Bandai clips, mean {statistics.mean(sizes) / 1024:.0f} KiB")
    print(f"parse only           : {parse_total / len(files) * 1000:6.2f} ms per clip")
    print(f"parse + FK + describe: {full_total / len(files) * 1000:6.2f} ms per clip (target 15)")
    print(f"  the same, CPU time : {full_cpu / len(files) * 1000:6.2f} ms per clip")
    print(f"largest file ({files[largest].name}, {sizes[largest] / 1e6:.1f} MB):")
    print(f"  parse only           : {largest_parse * 1000:6.1f} ms")
    print(f"  parse + FK + describe: {largest_full * 1000:6.1f} ms (target 60)")


if __name__ == "__main__":
    main()
