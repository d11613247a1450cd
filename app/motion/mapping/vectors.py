"""Small 3-vector arithmetic for the mapper."""

from __future__ import annotations

import math

import numpy as np


def _unit(v: np.ndarray) -> np.ndarray:
    n = _length(v)
    return v / n if n > 0 else v


# The mapper works on single 3-vectors, where numpy's general norm and cross cost 3-10 us a
# call; these do the same arithmetic (so give the same bits) in well under one.


def _length(v: np.ndarray) -> float:
    """Euclidean length of the 3-vector ``v`` (what ``np.linalg.norm`` computes)."""
    return math.sqrt(float(v @ v))


def _unit_rows(v: np.ndarray) -> np.ndarray:
    """``(..., 3)`` vectors ``v`` scaled to length 1 (zero vectors stay zero)."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` for 3-vectors (what ``np.cross`` computes)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
