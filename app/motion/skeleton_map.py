"""The structural skeleton mapper's public names (kept where every caller imports them;
the rules live in :mod:`app.motion.mapping`)."""

from __future__ import annotations

from app.motion.mapping.canonical import (
    CANONICAL_BONES,
    CANONICAL_INDEX,
    CANONICAL_JOINTS,
    CANONICAL_PARENT,
    FAMILY_NAMES,
    MIRROR_INDEX,
    SIDES,
    SkeletonMap,
    detect_family,
    rest_pose,
)
from app.motion.mapping.skeleton import map_skeleton
from app.motion.mapping.tree import COINCIDENT
from app.motion.skeleton_names import normalise_name

__all__ = [
    "CANONICAL_BONES",
    "CANONICAL_INDEX",
    "CANONICAL_JOINTS",
    "CANONICAL_PARENT",
    "COINCIDENT",
    "FAMILY_NAMES",
    "MIRROR_INDEX",
    "SIDES",
    "SkeletonMap",
    "detect_family",
    "map_skeleton",
    "normalise_name",
    "rest_pose",
]
