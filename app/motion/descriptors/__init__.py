"""Clip descriptors: one registry of name, dimension, version and compute function.

Every descriptor maps a :class:`~app.motion.body.Body` (canonical joints of one clip) to a
fixed-length float32 vector compared with the Euclidean distance. ``version`` changes whenever
the numbers a descriptor produces change, so stored vectors can be recomputed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from app.motion.body import Body


@dataclass(frozen=True)
class Descriptor:
    name: str
    dimension: int
    version: int
    description: str
    compute: Callable[[Body], np.ndarray]


def _registry() -> dict[str, Descriptor]:
    from app.motion.descriptors import kinetic, motion, posture

    found = [posture.DESCRIPTOR, kinetic.DESCRIPTOR, motion.DESCRIPTOR]
    return {d.name: d for d in found}


REGISTRY: dict[str, Descriptor] = _registry()


def get_descriptor(name: str) -> Descriptor:
    """The descriptor called ``name``; ``KeyError`` names the known ones."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown descriptor {name!r}; known: {', '.join(REGISTRY)}") from None
