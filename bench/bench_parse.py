"""Parse-time benchmark of the motion file readers on the shared real data.

Run from the repository root::

    .venv/bin/python bench/bench_parse.py [--repeat 5]

Reports milliseconds per file (best of ``--repeat`` runs, single process) for the average
Bandai BVH clip, the largest Bandai clip, the CMU BVH conversions and CMU ASF/AMC trials.
The data folder is ``../shared/data`` or ``$MOCAP_SHARED_DATA``.

Recorded (2 vCPU VM shared with other jobs, load ~2; best of 15; numpy 2.4, Python 3.11):

==========================================  ==========  ===========
files                                       mean        largest
==========================================  ==========  ===========
Bandai BVH (174, mean 224 KB), parse        1.9 ms      19.5 ms (2.4 MB)
Bandai BVH, parse + ``pipeline.analyse``    3.9 ms      32.7 ms
CMU MotionBuilder BVH (28, mean 2.0 MB)     31.9 ms     70.4 ms (3.9 MB)
CMU DAZ BVH (6, mean 446 KB)                4.5 ms      6.1 ms
CMU 3dsMax BVH (3, mean 784 KB)             10.0 ms     11.1 ms
CMU ASF/AMC (52 trials, mean 1.8 MB AMC)    35.2 ms     88.0 ms (4.2 MB)
==========================================  ==========  ===========

Where the time goes in the largest Bandai clip (1901 frames x 132 channels): numpy's C text
reader ~11.7 ms, Euler angles -> matrices ~4.5 ms, hierarchy + headers ~0.3 ms.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import shared_data  # bench/common.py (scripts run from bench/)

from app.motion.formats import read_asf_amc, read_bvh


def _best_ms(parse: Callable[[], object], repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        parse()
        best = min(best, time.perf_counter() - start)
    return best * 1e3


def _parse_and_analyse(data: bytes) -> object:
    from app.motion.pipeline import analyse  # optional: only with --pipeline

    return analyse(read_bvh(data))


def _report(label: str, timed: dict[Path, float], sizes: dict[Path, int]) -> None:
    largest = max(timed, key=lambda p: sizes[p])
    mean_ms = sum(timed.values()) / len(timed)
    mean_kb = sum(sizes[p] for p in timed) / len(timed) / 1024
    print(f"{label}: {len(timed)} files, mean {mean_kb:.0f} KB -> {mean_ms:.2f} ms per file")
    print(f"  largest {largest.name} ({sizes[largest] / 1e6:.1f} MB) -> {timed[largest]:.2f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument(
        "--pipeline", action="store_true", help="also time parse + app.motion.pipeline.analyse"
    )
    args = parser.parse_args()
    data = shared_data()
    if not data.is_dir():
        raise SystemExit(f"no shared data at {data} (set MOCAP_SHARED_DATA)")

    groups = {
        "Bandai BVH": sorted((data / "bandai-ds1" / "data").glob("*.bvh")),
        "CMU bvh-mb": sorted((data / "cmu" / "bvh-mb").rglob("*.bvh")),
        "CMU bvh-daz": sorted((data / "cmu" / "bvh-daz").rglob("*.bvh")),
        "CMU bvh-max": sorted((data / "cmu" / "bvh-max").rglob("*.bvh")),
    }
    for label, files in groups.items():
        if not files:
            continue
        contents = {path: path.read_bytes() for path in files}
        sizes = {path: len(b) for path, b in contents.items()}
        timed = {p: _best_ms(partial(read_bvh, contents[p]), args.repeat) for p in files}
        _report(label, timed, sizes)
        if args.pipeline:
            full = {
                p: _best_ms(partial(_parse_and_analyse, contents[p]), args.repeat) for p in files
            }
            _report(f"{label} parse + analyse", full, sizes)

    amc_files = sorted((data / "cmu" / "asf-amc").rglob("*.amc"))
    if amc_files:
        pairs = {
            amc: ((amc.parent / f"{amc.parent.name}.asf").read_bytes(), amc.read_bytes())
            for amc in amc_files
        }
        sizes = {amc: len(pair[1]) for amc, pair in pairs.items()}
        timed = {
            amc: _best_ms(partial(read_asf_amc, *pair), args.repeat) for amc, pair in pairs.items()
        }
        _report("CMU ASF/AMC", timed, sizes)


if __name__ == "__main__":
    main()
