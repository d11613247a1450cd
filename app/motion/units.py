"""Length units of a clip, and converting between them.

FBX and glTF clips are read in metres (the readers convert). BVH files do not say their
unit and ASF files only give a multiplier, so their unit is inferred from the body: of the
units motion files are written in (millimetres, centimetres, inches, Acclaim's default unit
of 1/0.45 inch — what ASF files with ``:units length 0.45`` and their BVH conversions use —,
decimetres, metres), the one that makes the body height (leg plus trunk bone path, about
0.83 of stature) nearest to an adult's 1.45 m. A child or a giant stays nearer its own unit
than the next one down or up as long as it is within about 1.5x of an adult.
"""

from __future__ import annotations

import numpy as np

UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "in": 0.0254}
"""Units an export may be written in, metres per unit."""

_CANDIDATES = (0.001, 0.01, 0.0254, 0.0254 / 0.45, 0.1, 1.0)
_TYPICAL_BODY_HEIGHT_M = 1.45
METRIC_FORMATS = ("fbx", "gltf")


def metres_per_unit(source_format: str, body_height: float) -> float:
    """Metres per length unit of a clip read from ``source_format`` whose body height (in
    its own units) is ``body_height`` (see the module docstring)."""
    if source_format in METRIC_FORMATS:
        return 1.0
    if not body_height > 0 or not np.isfinite(body_height):
        return 1.0
    errors = [abs(np.log(body_height * c / _TYPICAL_BODY_HEIGHT_M)) for c in _CANDIDATES]
    return _CANDIDATES[int(np.argmin(errors))]


def unit_name(metres: float) -> str:
    """``"cm"``, ``"m"``, ``"in"`` for a known unit, else ``"<x> m"``."""
    for name, value in UNITS.items():
        if abs(value - metres) <= 1e-12 * max(value, metres):
            return name
    return f"{metres:g} m"


__all__ = ["UNITS", "metres_per_unit", "unit_name"]
