"""Bookkeeping of a moments search (app/services/moment_finder.py) over sorted ids and window
rows: numbers kept per window id across a search's rounds, membership and distinct values of
sorted arrays without numpy's sorts, each window's distance to the nearest mark of its clip,
and the distinct moments among those placed.
"""

from __future__ import annotations

import numpy as np


class Known:
    """Numbers measured per window id, kept across a search's rounds: ``(N, C)`` float64
    rows, looked up by binary search."""

    def __init__(self, columns: int) -> None:
        self.ids = np.zeros(0, np.int64)
        self.values = np.zeros((0, columns))

    def find(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which of ``ids`` ``(M,)`` are known ``(M,)`` bool, and their rows ``(M, C)``
        (nan where unknown)."""
        at = np.minimum(np.searchsorted(self.ids, ids), max(self.ids.size - 1, 0))
        known = self.ids[at] == ids if self.ids.size else np.zeros(ids.size, bool)
        rows = np.full((ids.size, self.values.shape[1]), np.nan)
        rows[known] = self.values[at[known]]
        return known, rows

    def add(self, ids: np.ndarray, values: np.ndarray) -> None:
        """Keep rows ``values`` ``(M, C)`` of ``ids`` ``(M,)`` (none known yet): merged into
        place, not sorted again with every id known (a round adds hundreds to thousands)."""
        if ids.size > 1 and bool((ids[1:] < ids[:-1]).any()):
            order = np.argsort(ids, kind="stable")
            ids, values = ids[order], values[order]
        at = np.searchsorted(self.ids, ids, side="right")
        self.ids = np.insert(self.ids, at, ids)
        self.values = np.insert(self.values, at, values, axis=0)


def members(values: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Which of ``values`` ``(N,)`` are among ``keys`` ``(M,)`` (sorted, unique): ``(N,)``
    bool (``np.isin`` without its sort)."""
    if not keys.size:
        return np.zeros(values.size, bool)
    at = np.minimum(np.searchsorted(keys, values), keys.size - 1)
    return keys[at] == values


def distinct(ordered: np.ndarray) -> np.ndarray:
    """The distinct values of ``ordered`` ``(N,)`` (ascending): ``np.unique`` without its
    sort."""
    if ordered.size < 2:
        return ordered.copy()
    return ordered[np.r_[True, ordered[1:] != ordered[:-1]]]


def to_nearest(keys: np.ndarray, marks: np.ndarray) -> np.ndarray:
    """For each of ``keys`` ``(N,)``, how far the nearest of ``marks`` ``(M,)`` (ascending,
    M >= 1) is."""
    at = np.clip(np.searchsorted(marks, keys), 1, max(marks.size - 1, 1))
    below, above = marks[np.maximum(at - 1, 0)], marks[np.minimum(at, marks.size - 1)]
    return np.minimum(np.abs(keys - below), np.abs(keys - above))


def same_moments(groups: np.ndarray, placed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct moments among ``(groups, placed)`` ``(N,)`` (clip rows, starts): the row
    of each ``(K,)``, and which of them every moment is ``(N,)``."""
    order = np.lexsort((placed, groups))
    in_order = groups[order], placed[order]
    new = np.ones(groups.size, bool)
    new[1:] = (in_order[0][1:] != in_order[0][:-1]) | (in_order[1][1:] != in_order[1][:-1])
    again = np.empty(groups.size, np.int64)
    again[order] = np.cumsum(new) - 1
    return order[new], again


__all__ = ["Known", "distinct", "members", "same_moments", "to_nearest"]
