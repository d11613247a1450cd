"""Clip descriptors: one registry of name, dimension, version and compute function.

Every descriptor maps a :class:`~app.motion.body.Body` (canonical joints of one clip) to a
fixed-length float32 vector compared with the Euclidean distance. ``version`` changes whenever
the numbers a descriptor produces change, so stored vectors can be recomputed.

A descriptor is computed over frame spans (``compute_spans``): the whole clip is the span
``[0, F)``, and moment search describes many windows of one clip in the same pass (see
:mod:`app.motion.spans`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from app.motion.spans import whole_clip

if TYPE_CHECKING:
    from app.motion.body import Body

# The descriptor searches use unless told otherwise.
DEFAULT_DESCRIPTOR = "motion"


@dataclass(frozen=True)
class Descriptor:
    """A registered descriptor.

    ``compute_spans(body, spans)`` maps ``(W, 2)`` frame ranges ``[start, stop)`` of ``body``
    to ``(W, dimension)`` vectors; :meth:`compute` is the whole clip's vector.
    """

    name: str
    dimension: int
    version: int
    description: str
    compute_spans: Callable[[Body, np.ndarray], np.ndarray]

    def compute(self, body: Body) -> np.ndarray:
        """``(dimension,)`` the whole clip's vector."""
        return self.compute_spans(body, whole_clip(body.frame_count))[0]


def whole_clip_vector(descriptor: Descriptor) -> Callable[[Body], np.ndarray]:
    """The descriptor's whole-clip function, for modules that export ``compute_<name>``."""
    return descriptor.compute


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
