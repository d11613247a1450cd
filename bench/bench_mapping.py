"""Time the skeleton mapper alone: a rig seen for the first time, and every later clip.

Run: ``.venv/bin/python bench/bench_mapping.py [SHARED_DATA_DIR] [--repeat N]``

* First clip of a rig: every BVH file of ``wild-bvh`` (parsed first), the mapper's per-rig
  memo emptied before each, ``map_skeleton`` with the clip's frame poses (as ``build_body``
  offers them): median and worst over the files.
* Later clips: the 174 Bandai dataset-1 clips (one rig whose rest pose is no standing figure,
  so each clip reads its own frames), memo kept: mean per clip.

Best of ``--repeat`` runs. Compare with the same script of another branch on the same machine
in the same session (see bench/README.md).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import time
from pathlib import Path

from app.errors import MocapError, SkeletonMappingError
from app.motion.body import _frame_poses
from app.motion.formats import read_bvh
from app.motion.mapping import skeleton as skeleton_map
from app.motion.model import Motion


def _map(motion: Motion) -> None:
    with contextlib.suppress(SkeletonMappingError):  # refusals take time too
        skeleton_map.map_skeleton(motion.skeleton, _frame_poses(motion))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = Path(__file__).resolve().parents[1].parent / "shared" / "data"
    parser.add_argument("shared_data", nargs="?", type=Path, default=default)
    parser.add_argument("--repeat", type=int, default=3, help="best of N runs (default 3)")
    args = parser.parse_args()

    wild = []
    for path in sorted((args.shared_data / "wild-bvh").rglob("*.bvh")):
        try:
            wild.append(read_bvh(path.read_bytes()))
        except MocapError:  # files the reader refuses are not timed
            continue
    bandai = [
        read_bvh(p.read_bytes()) for p in sorted((args.shared_data / "bandai-ds1").rglob("*.bvh"))
    ]

    first = []
    for motion in wild:
        best = float("inf")
        for _ in range(args.repeat):
            skeleton_map._KNOWN.clear()
            start = time.perf_counter()
            _map(motion)
            best = min(best, time.perf_counter() - start)
        first.append(best)
    later = float("inf")
    for _ in range(args.repeat):
        skeleton_map._KNOWN.clear()
        _map(bandai[0])
        start = time.perf_counter()
        for motion in bandai:
            _map(motion)
        later = min(later, (time.perf_counter() - start) / len(bandai))
    print(
        f"first clip of a rig ({len(first)} wild-bvh files): median "
        f"{statistics.median(first) * 1000:.2f} ms, worst {max(first) * 1000:.1f} ms"
    )
    print(f"later clips ({len(bandai)} Bandai clips, one rig): {later * 1000:.3f} ms per clip")


if __name__ == "__main__":
    main()
