"""Near-identical clips (``collapse=capture``): where the thresholds of
``app/services/captures.py`` come from (issue 24, item 10).

Run from the repository root::

    .venv/bin/python bench/bench_captures.py [--data-dir DIR]

Imports Bandai dataset 1, every CMU folder (ASF/AMC, MotionBuilder, DAZ and 3ds Max BVH) and
the FBX/glTF set of ``../shared/data`` into ``DIR`` (a temporary folder by default), then
measures, under every descriptor:

* **twins**: one take on skeletons of the same proportions — a CMU trial's ASF/AMC and its
  MotionBuilder BVH, the FBX and BVH exports of one take (``pairs-*``), one FBX in versions
  6.1 and 7.4;
* **retargeted**: a CMU trial's ASF/AMC or MotionBuilder BVH and its DAZ / 3ds Max BVH (the
  motion put on another skeleton);
* **others**: every pair of clips of different takes (exactly identical vectors left out:
  the same motion stored twice, which any threshold merges);

and how many pairs of each kind the thresholds (all three descriptors at once) call
near-identical.
"""

from __future__ import annotations

import argparse
import re
import tempfile
from itertools import combinations
from pathlib import Path

import numpy as np
from common import machine, shared_data  # bench/common.py (scripts run from bench/)

from app.config import Settings
from app.db import clips as clip_db
from app.importer import run_import
from app.services.captures import NEAR_IDENTICAL
from app.services.library import open_library

# FBX/BVH exports of one take in fbx-gltf (file stems), and one FBX in two versions.
SAME_TAKE = [
    ("ortiz_hiphop", "ortiz_hiphop"),
    ("ortiz_situp_to_idle", "ortiz_situp_to_idle"),
    ("Geno_stance", "Geno_stance"),
    ("Geno_bind", "Geno_bind"),
    ("walk01", "template"),
    ("maya_human_ik_6100_ascii", "maya_human_ik_7400_binary"),
]


def take_of(clip: clip_db.ClipRecord) -> tuple[str, str]:
    """(take, kind): the CMU trial and which conversion, or the pair a file belongs to."""
    stem = Path(clip.filenames[-1]).stem
    if re.fullmatch(r"\d+_\d+", stem):
        family = clip.skeleton_family
        kind = "asf" if clip.format == "asf/amc" else family
        return f"cmu {stem}", kind
    for a, b in SAME_TAKE:
        if stem in (a, b):
            return f"pair {a}", f"{clip.format} {stem}"
    return f"clip {clip.id}", ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--data-dir", type=Path, default=None)
    args = parser.parse_args()
    data = shared_data()
    with tempfile.TemporaryDirectory(prefix="mocap-bench-captures-") as tmp:
        data_dir = args.data_dir or Path(tmp) / "data"
        settings = Settings(data_dir=data_dir, log_level="warning")
        if not (data_dir / "mocap-index.sqlite3").exists():
            run_import(settings, [data / "bandai-ds1", data / "cmu", data / "fbx-gltf"])
        library = open_library(settings)
        try:
            with library.reads() as session:
                clips = clip_db.get_clips(session, clip_db.all_clip_ids(session))
            ids = np.array(sorted(clips), np.int64)
            vectors = {}
            for name, index in library.indexes.items():
                held, found = index.reconstruct_batch(ids)
                assert held.all(), name
                vectors[name] = found.astype(np.float64)
            versions = {name: info.version for name, info in library.descriptors.items()}
        finally:
            library.close()
    takes = [take_of(clips[int(i)]) for i in ids]
    kinds: dict[str, list[tuple[int, int]]] = {"twins": [], "retargeted": [], "others": []}
    for a, b in combinations(range(ids.size), 2):
        (take_a, kind_a), (take_b, kind_b) = takes[a], takes[b]
        if take_a != take_b:
            kinds["others"].append((a, b))
        elif take_a.startswith("cmu") and {kind_a, kind_b} - {"asf", "motionbuilder"}:
            kinds["retargeted"].append((a, b))
        else:
            kinds["twins"].append((a, b))
    print(f"machine: {machine()}")
    print(f"{ids.size} clips; thresholds {NEAR_IDENTICAL}")
    merged = {}
    for kind, pairs in kinds.items():
        first, second = (np.array(side) for side in zip(*pairs, strict=True))
        distances = {
            name: np.linalg.norm(v[first] - v[second], axis=1) for name, v in vectors.items()
        }
        identical = np.logical_and.reduce([d < 1e-9 for d in distances.values()])
        near = np.logical_and.reduce(
            [d <= NEAR_IDENTICAL[(name, versions[name])] for name, d in distances.items()]
        )
        for name, d in distances.items():
            d = d[~identical] if kind == "others" else d
            low, mid, high = np.percentile(d, [0, 50, 100])
            print(f"  {kind:10s} {name:8s}: min {low:.4f}  median {mid:.4f}  max {high:.4f}")
        counted = near[~identical] if kind == "others" else near
        merged[kind] = (int(counted.sum()), int(counted.size))
    for kind, (count, total) in merged.items():
        print(f"near-identical under all three: {kind} {count}/{total} pairs")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
