"""CPU of the skeleton mapper on the dev BVH files and their no-standing-figure probes,
this checkout against a baseline checkout, alternately in one run.

Run from the repository root::

    .venv/bin/python bench/bench_mapper_cpu.py --baseline CHECKOUT [--files 12] [--rounds 4]

The workload of ``tests/motion/test_mapping_rest.py``: the first ``--files`` human BVH files
of ``wild-bvh`` and ``wild-more`` (``tests.motion.test_nameless_real.FILES``), 120 frames
each, and their probes (``rest_probes``: seated, crouched, lying takes and frames that do not
stand, written as the rest pose). Each round, a fresh process of each checkout (baseline
first, then this one; the same Python, each checkout first on the path) builds the motions
and their frame poses untimed, empties the mapper's per-rig memo and maps every one with
``map_skeleton``: the CPU seconds (``time.process_time``) of the mapping alone, and a digest
of every mapping (joints, mirrored, warnings, or the refusal's message) that must be the same
for both. Prints each round's figures, the median ratio and the load average.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

_ONE_ROUND = """
import hashlib, sys, time
from app.errors import SkeletonMappingError
from app.motion.body import _frame_poses
from app.motion.formats import read_bvh
from app.motion.ground import sample_frames
from app.motion.mapping import skeleton as mapping
from tests.motion.test_mapping_rest import rest_probes
from tests.motion.test_nameless_real import FILES

motions = []
for path in FILES[: int(sys.argv[1])]:
    motion = sample_frames(read_bvh(path.read_bytes()), 120)
    motions += [motion, *rest_probes(motion).values()]
work = [(m.skeleton, list(_frame_poses(m))) for m in motions]
mapping._KNOWN.clear()
digest = hashlib.sha1()
start = time.process_time()
for skeleton, poses in work:
    try:
        found = mapping.map_skeleton(skeleton, poses)
        digest.update(repr((found.joints.tolist(), found.mirrored, found.warnings)).encode())
    except SkeletonMappingError as error:
        digest.update(str(error).encode())
print(len(work), time.process_time() - start, digest.hexdigest())
"""


def _round(checkout: Path, files: int) -> tuple[int, float, str]:
    done = subprocess.run(
        [sys.executable, "-c", _ONE_ROUND, str(files)],
        cwd=checkout,
        env={**os.environ, "PYTHONPATH": str(checkout)},
        capture_output=True,
        text=True,
        check=True,
    )
    count, seconds, digest = done.stdout.split()
    return int(count), float(seconds), digest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="checkout to compare with")
    parser.add_argument("--files", type=int, default=12, help="dev BVH files (default 12)")
    parser.add_argument("--rounds", type=int, default=4, help="alternated rounds (default 4)")
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[1]
    baseline = args.baseline.resolve()
    times: dict[Path, list[float]] = {baseline: [], here: []}
    digests: dict[Path, set[str]] = {baseline: set(), here: set()}
    for index in range(args.rounds):
        for checkout in (baseline, here):
            count, seconds, digest = _round(checkout, args.files)
            times[checkout].append(seconds)
            digests[checkout].add(digest)
            print(f"round {index + 1} {checkout}: {count} mappings, CPU {seconds:.2f} s")
    print(f"load average {os.getloadavg()[0]:.2f} after {args.rounds} rounds")
    for checkout, values in times.items():
        print(f"{checkout}: CPU median {statistics.median(values):.2f} s, best {min(values):.2f}")
    ratio = statistics.median(times[here]) / statistics.median(times[baseline])
    print(f"this checkout / baseline: {ratio:.3f} (median)")
    same = digests[here] == digests[baseline] and len(digests[here]) == 1
    print("mappings identical" if same else f"MAPPINGS DIFFER: {digests}")


if __name__ == "__main__":
    main()
