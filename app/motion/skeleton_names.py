"""Joint names as hints: which body part and which side a name says, compared whole.

A name is split into tokens at separators (``_ - . : |`` and spaces), lower-cased; tool
prefixes are whatever leading tokens make the rest a known name (``mixamorig:LeftArm``,
``f_avg_L_Hip``, ``Bip01_L_Thigh``), so no list of exporters is needed. What remains must
*equal* a side form of a known base word (``leftupleg``, ``lupleg``, ``uplegl``,
``uplegleft``), with trailing digits of the base ignored (``upperarm01.L`` -> ``upperarm``).
Substrings never count: ``LeftUpLegHelper`` says nothing.

The mapper (:mod:`app.motion.skeleton_map`) uses these hints only to break ties that the
skeleton's structure and rest-pose geometry leave open, and to name sides.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_SEPARATORS = re.compile(r"[\s_\-.:|]+")

# Body part -> base words, best first. A base may hint more than one part (``shoulder`` is the
# clavicle in MotionBuilder rigs and the upper arm in 3ds Max and Kinect ones): its rank in
# each list says how strongly.
SIDED_PARTS: dict[str, tuple[str, ...]] = {
    "clavicle": ("clavicle", "collar", "shoulder"),
    "shoulder": ("arm", "upperarm", "uparm", "shldr", "humerus", "shoulder", "bicep"),
    "elbow": ("forearm", "lowerarm", "lowarm", "loarm", "elbow", "radius", "ulna"),
    "wrist": ("wrist", "hand"),
    "hip": ("upleg", "upperleg", "thigh", "femur", "hip", "uleg"),
    "knee": ("leg", "lowerleg", "lowleg", "loleg", "shin", "knee", "tibia", "calf", "lleg"),
    "ankle": ("foot", "ankle"),
    "toe": ("toebase", "toe", "toes", "ball"),
}
UNSIDED_PARTS: dict[str, tuple[str, ...]] = {
    "pelvis": ("hips", "hip", "pelvis", "root"),
    "neck": ("lowerneck", "neck", "upperneck"),
    "head": ("head",),
}
ARM_PARTS = frozenset({"clavicle", "shoulder", "elbow", "wrist"})
LEG_PARTS = frozenset({"hip", "knee", "ankle", "toe"})

_SIDE_WORDS = {"left": "l", "right": "r", "l": "l", "r": "r"}


@dataclass(frozen=True)
class NameHint:
    """What one joint name says: ``side`` ``"l"``/``"r"``/None and part -> rank (0 = best)."""

    side: str | None
    parts: dict[str, int]


def normalise_name(name: str) -> str:
    """Lower-case ``name`` without namespace or separators: ``mixamorig:LeftArm`` ->
    ``leftarm``, ``UpperLeg_L`` -> ``upperlegl``."""
    lowered = name.strip().lower()
    if ":" in lowered:
        lowered = lowered.rsplit(":", 1)[1]
    return _SEPARATORS.sub("", lowered)


def _tokens(name: str) -> list[str]:
    return [t for t in _SEPARATORS.split(name.strip().lower()) if t]


def _base_parts(base: str, table: dict[str, tuple[str, ...]]) -> dict[str, int]:
    # The trailing digits, stripped in one pass: ``re.sub(r"\d+$")`` retried every start in
    # a long run of digits not at the end (a 25,677-digit name took 12 s and held the server).
    end = len(base)
    while end and base[end - 1].isdecimal():
        end -= 1
    base = base[:end]
    return {part: bases.index(base) for part, bases in table.items() if base in bases}


def _split_side(compact: str) -> list[tuple[str, str]]:
    """Every (side, base) reading of ``compact`` with a side word at one end."""
    readings = []
    for word, side in _SIDE_WORDS.items():
        if compact.startswith(word) and len(compact) > len(word):
            readings.append((side, compact[len(word) :]))
        if compact.endswith(word) and len(compact) > len(word):
            readings.append((side, compact[: -len(word)]))
    return readings


def name_hint(name: str) -> NameHint:
    """The side and body parts ``name`` names (empty when it names none)."""
    tokens = _tokens(name)
    # Longest tail of tokens first: leading tokens are tool prefixes only when the rest is a
    # known name on its own.
    for start in range(len(tokens)):
        compact = "".join(tokens[start:])
        if not compact:
            continue
        for side, base in _split_side(compact):
            parts = _base_parts(base, SIDED_PARTS)
            if parts:
                return NameHint(side, parts)
        parts = _base_parts(compact, UNSIDED_PARTS)
        if parts:
            return NameHint(None, parts)
    return NameHint(None, {})


def name_side(name: str) -> str | None:
    """``"l"``/``"r"`` when ``name`` says a side in a whole-name form (any word), else None.

    ``lfemur``, ``LeftFooBar``, ``foo.L``, ``Bip01 R Bar``: a side word standing at either end
    of the name or as a token of its own.
    """
    tokens = _tokens(name)
    for token in tokens:
        if token in _SIDE_WORDS:
            return _SIDE_WORDS[token]
    hint = name_hint(name)
    if hint.side is not None:
        return hint.side
    compact = "".join(tokens)
    for word in ("left", "right"):
        if compact.startswith(word) or compact.endswith(word):
            return _SIDE_WORDS[word]
    return None
