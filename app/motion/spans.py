"""Means of per-frame quantities over any run of frames in O(1): prefix sums.

Every descriptor is a function of means (and means of squares) of per-frame quantities over
the frames it describes. Computing them through :class:`RunningMeans` gives the whole clip
and any number of windows inside it (moment search) from one pass over the frames, and the
whole-clip vector is by construction the vector of the window covering the whole clip.

Still stretches
---------------
A run of frames in which nothing moves is a valid input, and its means must be what the
definitions say, exactly: zero energy, zero speed, zero spread. Prefix sums are therefore
plain running sums of the samples. A run of exact zeros adds exactly nothing (``s + 0.0 ==
s``), so its mean is exactly 0, of either sign of quantity; the sums of a quantity that
cannot be negative never decrease (rounding is monotone), so its means are never negative.
(Sums of deviations from the clip's mean, used before, lost both properties: a still window
got a mean energy of -1e-17, and a logarithm or square root of it is not a number.) On a
ten-minute take at 120 fps the plain sums move a window's values by ~1e-10 (measured), far below
what a float32 vector keeps.
"""

from __future__ import annotations

import numpy as np


class RunningMeans:
    """Prefix sums of ``(N, ...)`` per-sample rows.

    Sample ``i`` belongs to frame ``i`` (plus a fixed offset the caller applies); the mean of
    samples ``start:stop`` costs O(row size) whatever the length of the run, is exactly 0 over
    a run of zeros and never negative for samples that are not (see the module docstring).
    """

    def __init__(self, samples: np.ndarray) -> None:
        samples = np.asarray(samples, dtype=np.float64)
        self.row_shape: tuple[int, ...] = samples.shape[1:]
        # An explicit row size: a one-frame clip has no velocity samples (0 rows).
        flat = samples.reshape(samples.shape[0], int(np.prod(self.row_shape, dtype=np.int64)))
        self._prefix = np.zeros((flat.shape[0] + 1, flat.shape[1]))
        np.cumsum(flat, axis=0, out=self._prefix[1:])

    @property
    def count(self) -> int:
        """Number of samples."""
        return self._prefix.shape[0] - 1

    def mean(self, starts: np.ndarray, stops: np.ndarray) -> np.ndarray:
        """``(W, *row_shape)`` mean of samples ``starts[w]:stops[w]`` (clipped to the samples);
        an empty run gives zeros."""
        starts = np.clip(np.asarray(starts, dtype=np.int64), 0, self.count)
        stops = np.clip(np.asarray(stops, dtype=np.int64), 0, self.count)
        lengths = np.maximum(stops - starts, 0)
        sums = self._prefix[np.maximum(stops, starts)] - self._prefix[starts]
        means = sums / np.maximum(lengths, 1)[:, None]  # an empty run: 0 / 1
        return means.reshape((len(starts), *self.row_shape))


def std_from_moments(mean: np.ndarray, mean_square: np.ndarray) -> np.ndarray:
    """Population standard deviation from the mean and the mean of squares (0, not a NaN,
    where rounding makes the variance of a constant run a hair below zero)."""
    return np.sqrt(np.maximum(mean_square - mean * mean, 0.0))


def whole_clip(frame_count: int) -> np.ndarray:
    """``(1, 2)`` the span ``[0, frame_count)``."""
    return np.array([[0, frame_count]], dtype=np.int64)
