"""Compute the frozen block scales of the ``motion`` descriptor from the reference corpus.

The reference corpus is Bandai dataset 1 and the CMU clips (all formats) of
``../shared/data``. For each block the scale is the square root of the summed per-dimension
variance over the corpus, so every block contributes unit total variance before its weight.
The printed constants are pasted into ``app/motion/descriptors/motion.py`` together with a
version bump; they never change at run time, so a clip's vector does not depend on the
library it is stored in.

Run: ``.venv/bin/python bench/motion_scales.py [SHARED_DATA_DIR]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from app.discovery import discover
from app.motion.body import build_body
from app.motion.descriptors.motion import motion_blocks
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import Motion
from app.motion.spans import whole_clip

REFERENCE_FOLDERS = ("bandai-ds1", "cmu")


def corpus(root: Path) -> list[Motion]:
    motions = []
    for source in discover([root / folder for folder in REFERENCE_FOLDERS]).sources:
        data = [path.read_bytes() for path in source.paths]
        motions.append(read_bvh(data[0]) if source.kind == "bvh" else read_asf_amc(*data))
    return motions


def main() -> None:
    root = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
    rows = []
    for motion in corpus(root):
        body = build_body(motion)
        rows.append({k: v[0] for k, v in motion_blocks(body, whole_clip(body.frame_count)).items()})
    print(f"# {len(rows)} clips from {root}")
    print("BLOCK_SCALES = {")
    for name in rows[0]:
        values = np.stack([row[name] for row in rows])
        print(f'    "{name}": {float(np.sqrt(values.var(axis=0).sum())):.3g},')
    print("}")


if __name__ == "__main__":
    main()
