"""Compute the frozen block scales of the ``motion`` descriptor from the reference corpus.

The reference corpus is every clip of ``../shared/data`` (Bandai dataset 1 and the CMU
clips in all formats). For each block (limbs, energy, travel) the scale is the square root
of the summed per-dimension variance over the corpus, so every block contributes unit total
variance before its weight. The printed constants are pasted into
``app/motion/descriptors/motion.py`` together with a version bump; they never change at run
time, so a clip's vector does not depend on the library it is stored in.

Run: ``.venv/bin/python bench/motion_scales.py [SHARED_DATA_DIR]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from app.motion.body import build_body
from app.motion.descriptors.kinetic import compute_kinetic
from app.motion.descriptors.motion import limb_block, travel_block
from app.motion.formats import read_asf_amc, read_bvh


def corpus(root: Path) -> list:
    motions = []
    for path in sorted(root.rglob("*.bvh")):
        motions.append(read_bvh(path.read_bytes()))
    for amc in sorted(root.rglob("*.amc")):
        subject = amc.stem.split("_")[0]
        asf = amc.with_name(f"{subject}.asf")
        motions.append(read_asf_amc(asf.read_bytes(), amc.read_bytes()))
    return motions


def main() -> None:
    root = (
        Path(sys.argv[1])
        if len(sys.argv) > 1
        else Path(__file__).resolve().parents[1].parent / "shared" / "data"
    )
    bodies = [build_body(m) for m in corpus(root)]
    blocks = {
        "limbs": np.stack([limb_block(b) for b in bodies]),
        "energy": np.stack([compute_kinetic(b) for b in bodies]),
        "travel": np.stack([travel_block(b) for b in bodies]),
    }
    print(f"# {len(bodies)} clips from {root}")
    print("BLOCK_SCALES = {")
    for name, values in blocks.items():
        print(f'    "{name}": {float(np.sqrt(values.var(axis=0).sum())):.6g},')
    print("}")


if __name__ == "__main__":
    main()
