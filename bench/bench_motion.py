"""Time parse + forward kinematics + descriptors, single process, on Bandai dataset 1.

Run: ``.venv/bin/python bench/bench_motion.py [SHARED_DATA_DIR] [--repeat N]``

Reports the mean time per clip over the 174 clips (files read into memory first, so disk
is not timed), the time for the largest file, and the split between parsing and analysis
(canonical mapping, lead-in detection, FK and every registered descriptor). Targets
(issue 2): at most 15 ms per average clip and 60 ms for the largest file.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

from app.motion.descriptors import REGISTRY
from app.motion.formats import read_bvh
from app.motion.pipeline import analyse


def _time(fn, repeat: int) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    parser.add_argument("shared_data", nargs="?", type=Path, default=default)
    parser.add_argument("--repeat", type=int, default=3, help="best of N runs (default 3)")
    args = parser.parse_args()

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
    largest_parse = _time(lambda: read_bvh(blobs[largest]), args.repeat * 3)
    largest_full = _time(lambda: analyse(read_bvh(blobs[largest])), args.repeat * 3)
    sizes = [len(b) for b in blobs]
    machine = f"{platform.machine()} {platform.processor()}".strip()
    print(f"machine: {machine}, python {platform.python_version()}")
    print(f"descriptors: {', '.join(REGISTRY)}")
    print(f"{len(files)} Bandai clips, mean {statistics.mean(sizes) / 1024:.0f} KiB")
    print(f"parse only           : {parse_total / len(files) * 1000:6.2f} ms per clip")
    print(f"parse + FK + describe: {full_total / len(files) * 1000:6.2f} ms per clip (target 15)")
    print(f"largest file ({files[largest].name}, {sizes[largest] / 1e6:.1f} MB):")
    print(f"  parse only           : {largest_parse * 1000:6.1f} ms")
    print(f"  parse + FK + describe: {largest_full * 1000:6.1f} ms (target 60)")


if __name__ == "__main__":
    main()
