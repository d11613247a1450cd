"""Means of per-frame quantities over any run of frames in O(1): prefix sums.

Every descriptor is a function of means (and means of squares) of per-frame quantities over
the frames it describes. Computing them through :class:`RunningMeans` gives the whole clip
and any number of windows inside it (moment search) from one pass over the frames, and the
whole-clip vector is by construction the vector of the window covering the whole clip.

Still stretches
---------------
A run of frames in which nothing moves is a valid input, and its means must be what the
definitions say, exactly: zero energy, zero speed, zero spread. Quantities that cannot be
negative (energies, squares, speeds) are therefore declared ``nonnegative``: their prefix
sums are plain running sums, which never decrease (adding a number >= 0 cannot lower a
rounded float sum), so every mean is >= 0, and a run of exact zeros adds exactly nothing and
has mean exactly 0. Signed quantities are summed as deviations from the overall mean, so a
long clip loses no precision to large sums.
"""

from __future__ import annotations

import numpy as np


class RunningMeans:
    """Prefix sums of ``(N, ...)`` per-sample rows.

    Sample ``i`` belongs to frame ``i`` (plus a fixed offset the caller applies); the mean of
    samples ``start:stop`` costs O(row size) whatever the length of the run.

    Parameters
    ----------
    samples:
        ``(N, ...)`` rows.
    nonnegative:
        ``True`` when every entry is >= 0 (or a boolean mask of the row's entries that are):
        their means are then never negative, and exactly 0 over a run of zeros (see the
        module docstring).
    """

    def __init__(self, samples: np.ndarray, *, nonnegative: bool | np.ndarray = False) -> None:
        samples = np.asarray(samples, dtype=np.float64)
        self.row_shape: tuple[int, ...] = samples.shape[1:]
        # An explicit row size: a one-frame clip has no velocity samples (0 rows).
        size = int(np.prod(self.row_shape, dtype=np.int64))
        flat = samples.reshape(samples.shape[0], size)
        self._nonnegative = np.broadcast_to(np.asarray(nonnegative, dtype=bool), self.row_shape)
        self._nonnegative = self._nonnegative.reshape(size)
        # Signed entries: sums of deviations from the overall mean (no precision lost to large
        # sums); entries >= 0: plain sums (monotone, exact over runs of zeros).
        offset = flat.mean(axis=0) if flat.shape[0] else np.zeros(size)
        self._offset = np.where(self._nonnegative, 0.0, offset)
        self._prefix = np.zeros((flat.shape[0] + 1, size))
        np.cumsum(flat - self._offset, axis=0, out=self._prefix[1:])

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
        means = np.where(
            lengths[:, None] > 0, sums / np.maximum(lengths, 1)[:, None] + self._offset, 0.0
        )
        # Plain sums never decrease, so this only removes the sign of a zero (-0.0).
        means = np.where(self._nonnegative, np.maximum(means, 0.0), means)
        return means.reshape((len(starts), *self.row_shape))


def std_from_moments(mean: np.ndarray, mean_square: np.ndarray) -> np.ndarray:
    """Population standard deviation from the mean and the mean of squares (0, not a NaN,
    where rounding makes the variance of a constant run a hair below zero)."""
    return np.sqrt(np.maximum(mean_square - mean * mean, 0.0))


def whole_clip(frame_count: int) -> np.ndarray:
    """``(1, 2)`` the span ``[0, frame_count)``."""
    return np.array([[0, frame_count]], dtype=np.int64)
