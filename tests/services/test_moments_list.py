"""The moments' list (app/services/moments.py): choosing the first ``k`` stops at the k-th
and gives what walking every placed moment gives."""

from __future__ import annotations

import numpy as np
import pytest

from app.services.moment_finder import PlacedMoments
from app.services.moments import _chosen


@pytest.mark.parametrize("seed", range(20))
def test_choosing_the_first_k_is_the_start_of_the_whole_list(seed: int) -> None:
    rng = np.random.default_rng(seed)
    count = int(rng.integers(1, 400))
    clips = rng.integers(1, 12, count)
    starts = rng.integers(0, 40, count) * 0.25
    spans = rng.choice([1.0, 2.5, 4.0], count)
    # Ties in distance and repeated (clip, start) pairs: the order's tie-breaks matter.
    found = PlacedMoments(clips, starts, starts + spans, rng.integers(0, 30, count) * 0.1)
    frame_of = {int(c): 1 / 30 for c in np.unique(clips)}
    exclude = (int(clips[0]), 0, 60) if seed % 2 else None
    per_clip = int(rng.integers(1, 4))
    every = _chosen(found, per_clip, exclude, frame_of, count)
    for most in (1, 3, 10, 30):
        assert _chosen(found, per_clip, exclude, frame_of, most) == every[:most]
