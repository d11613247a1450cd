"""Dev files read once per test module: the parsed clip shared by several read-only tests,
its arrays made read-only so that a test (or the code it runs) that writes into them fails
loudly instead of changing what the next test sees."""

from __future__ import annotations

import numpy as np

from app.motion.model import Motion


def read_only(motion: Motion) -> Motion:
    """``motion`` with every array (skeleton's and frames') flagged not writeable."""
    arrays = (
        motion.skeleton.parents,
        motion.skeleton.offsets,
        motion.skeleton.end_site,
        motion.root_translation,
        motion.local_rotations,
        motion.local_translations,
    )
    for array in arrays:
        if isinstance(array, np.ndarray):
            array.flags.writeable = False
    return motion
