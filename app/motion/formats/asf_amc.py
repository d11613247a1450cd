"""Acclaim ASF (skeleton) + AMC (motion) text -> :class:`~app.motion.model.Motion`.

What the numbers mean
---------------------
ASF (one per subject):

* ``:units`` -- ``mass`` (ignored), ``length`` (a multiplier: real length = file length /
  multiplier; the CMU files say ``length 0.45``, which makes inches), ``angle deg|rad``.
* ``:root`` -- ``order`` (which AMC ``root`` values are translations ``TX TY TZ`` and rotations
  ``RX RY RZ``, in file order), ``axis`` + ``orientation`` (the root's axis frame ``C_root``),
  ``position`` (added to the AMC root translation).
* ``:bonedata`` -- per bone: ``direction`` (unit vector in the world frame at rest),
  ``length`` (file units), ``axis a1 a2 a3 ORDER`` (the bone's axis frame ``C_b``, Euler
  angles applied **extrinsically** in ``ORDER``: ``XYZ`` means ``C = Rz @ Ry @ Rx``), ``dof``
  (which AMC values the bone has, in file order: ``rx ry rz`` rotations about the bone's
  axes, ``tx ty tz`` translations along them, ``l`` stretching along the bone),
  ``limits`` (ignored).
* ``:hierarchy`` -- ``parent child child ...`` lines.

AMC (one per trial): optional header lines starting with ``#`` or ``:`` (``:DEGREES`` /
``:RADIANS`` override the ASF angle unit), then per frame a frame-number line followed by one
line per bone that has a dof, ``name value value ...``, in any order. AMC has no frame rate;
the CMU database is 120 fps, so :data:`DEFAULT_AMC_FRAME_TIME` is ``1/120`` s. Every bone with
a dof must appear in every frame (a missing bone is an error, never a silent zero; the CMU
files always list them all).

How the joint skeleton is built (as the CMU -> BVH converters do)
-----------------------------------------------------------------
Joint 0 is ``"root"``. Each bone becomes a joint at the bone's *start* (its parent bone's
end), named after the bone; its offset is the parent bone's ``direction * length``
(zero for children of the root). Each leaf bone also gets an End Site joint
``"<bone>_end"`` at its tip. All lengths are divided by the ``:units length`` multiplier
(``Motion.length_unit`` says which unit results). The local rotation of bone ``b`` is
``L_b = C_b @ M_b @ C_b.T`` where ``M_b`` composes the AMC rotation values extrinsically in the
``dof`` order (``rx ry rz`` -> ``M = Rz @ Ry @ Rx``); the root's is
``L_root = C_root @ M_root @ C_root.T`` with ``M_root`` from the ``RX RY RZ`` values in
``:root order``. Translation dofs give ``Motion.local_translations``.

The AMC's lines are read into a table of values by :mod:`app.motion.formats.amc`, and the
motion is built from it by :mod:`app.motion.formats.asf_build`. Either
file may write its numbers with decimal commas (``0,45``, a tool under a European locale):
each is read with points then, and a warning says which (as a BVH file so written is).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from app.errors import LimitExceeded, ParseError
from app.motion.formats.amc import read_amc
from app.motion.formats.asf_build import build_motion
from app.motion.formats.text import (
    DECIMAL_COMMA_HEAD,
    DECIMAL_COMMA_WARNING,
    DEFAULT_LIMITS,
    LINES_PER_CLOCK_CHECK,
    decimal_comma,
    normalise_newlines,
    parse_float,
    show,
)
from app.motion.model import Motion, ParseLimits

__all__ = ["DEFAULT_AMC_FRAME_TIME", "parse_asf_amc"]

#: Seconds per frame of an AMC file: the CMU database is captured at 120 fps.
DEFAULT_AMC_FRAME_TIME = 1.0 / 120.0

# The ASF fields that hold numbers (``:units`` mass and length, ``:root`` and bone fields).
_ASF_NUMBER_FIELDS = frozenset({"mass", "length", "direction", "axis", "position", "orientation"})
_BONE_DOFS = frozenset({"rx", "ry", "rz", "tx", "ty", "tz", "l"})
_ROOT_DOFS = frozenset({"rx", "ry", "rz", "tx", "ty", "tz"})
_ANGLE_UNITS = {
    "deg": "deg",
    "degree": "deg",
    "degrees": "deg",
    "rad": "rad",
    "radian": "rad",
    "radians": "rad",
}
_AXIS_RE = re.compile(r"[XYZ]{3}", re.IGNORECASE)
# Bone fields we read or knowingly ignore; anything else in a bone block is an error.
_IGNORED_BONE_FIELDS = frozenset({"id", "limits", "bodymass", "cofmass"})
# How far a bone's ``direction`` may be from unit length and still be read as written (the
# CMU files' six decimals are within 1e-6).
_UNIT_TOLERANCE = 1e-3


@dataclass
class _Bone:
    """One ASF bone (or the root, with ``name="root"``) while reading."""

    name: str
    line: int
    direction: tuple[float, float, float] | None = None
    length: float | None = None
    axis_angles: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis_order: str = "XYZ"
    dof: list[str] = field(default_factory=list)
    children: list[str] = field(default_factory=list)
    parent: str | None = None


@dataclass
class _Asf:
    """What the ASF says, in file units."""

    length_multiplier: float = 1.0
    angle_unit: str = "deg"
    root: _Bone = field(default_factory=lambda: _Bone(name="root", line=0))
    root_position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    root_orientation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    bones: dict[str, _Bone] = field(default_factory=dict)  # name -> bone, file order
    name: str | None = None
    warnings: list[str] = field(default_factory=list)


def parse_asf_amc(
    asf_text: str,
    amc_text: str,
    *,
    limits: ParseLimits = DEFAULT_LIMITS,
    frame_time: float = DEFAULT_AMC_FRAME_TIME,
) -> Motion:
    """Read an ASF skeleton and one AMC motion, both already decoded to text.

    Parameters
    ----------
    asf_text, amc_text:
        Whole files; ``\\r\\n`` line ends are accepted.
    limits:
        Upper bounds on joints, nesting depth, frames and values.
    frame_time:
        Seconds per frame (AMC files do not say); default ``1/120`` (CMU).

    Returns
    -------
    Motion
        ``source_format="asf/amc"``; see the module docstring.

    Raises
    ------
    ParseError
        ``source`` is ``"ASF"`` or ``"AMC"``; ``line`` says where when it applies.
    LimitExceeded
    """
    if not (isinstance(frame_time, int | float) and math.isfinite(frame_time) and frame_time > 0):
        raise ParseError(f"frame_time must be a positive number of seconds, not {frame_time!r}")
    limits.check_time()
    asf_text, asf_commas = _with_decimal_points(asf_text, _ASF_NUMBER_FIELDS)
    amc_text, amc_commas = _with_decimal_points(amc_text, None)
    try:
        asf = _parse_asf(_split_lines(asf_text), limits)
        joints = _order_joints(asf, limits)
    except ParseError as error:
        raise error.with_source("ASF") from None
    layout = _column_layout(asf)
    dofs = {bone.name: bone.dof for bone in (asf.root, *asf.bones.values())}
    try:
        values, first_frame, amc_angle_unit, warnings = read_amc(
            _split_lines(amc_text), dofs, layout, len(joints), limits
        )
    except ParseError as error:
        raise error.with_source("AMC") from None
    angle_unit = amc_angle_unit or asf.angle_unit
    motion = build_motion(asf, joints, layout, values, angle_unit, frame_time, first_frame)
    commas = [
        f"{source}: {DECIMAL_COMMA_WARNING}"
        for source, said in (("ASF", asf_commas), ("AMC", amc_commas))
        if said
    ]
    if commas or warnings or asf.warnings:
        motion.notes["warnings"] = [*commas, *asf.warnings, *warnings]
    return motion


def parse_asf_rest(
    asf_text: str,
    *,
    limits: ParseLimits = DEFAULT_LIMITS,
    frame_time: float = DEFAULT_AMC_FRAME_TIME,
) -> Motion:
    """An ASF skeleton alone, as one frame of its rest pose (every degree of freedom 0): a
    rig to retarget onto. Raises like :func:`parse_asf_amc` (``source="ASF"``)."""
    asf_text, _ = _with_decimal_points(asf_text, _ASF_NUMBER_FIELDS)
    try:
        asf = _parse_asf(_split_lines(asf_text), limits)
        joints = _order_joints(asf, limits)
    except ParseError as error:
        raise error.with_source("ASF") from None
    layout = _column_layout(asf)
    columns = sum(count for _, count in layout.values())
    values = np.zeros((1, columns))
    return build_motion(asf, joints, layout, values, asf.angle_unit, frame_time, 1)


def _with_decimal_points(text: str, fields: frozenset[str] | None) -> tuple[str, bool]:
    """``text`` with decimal commas read as points when its numbers are written so (a tool
    under a European locale: ``direction 0,5 -0,2 0,8``, AMC ``lfemur -12,5 3,1 0``), and
    whether they were. The numbers looked at are those of the first lines
    (:data:`DECIMAL_COMMA_HEAD`): every word after the first on the ASF lines whose first
    word is one of ``fields``, or on every AMC line (``fields`` None) that is not a header
    or comment. The words are ASCII either way, so a comma is never part of a name."""
    tokens: list[str] = []
    for line in text[:DECIMAL_COMMA_HEAD].split("\n"):
        words = line.split()
        if not words or words[0].startswith(("#", ":")):
            continue
        if fields is None or words[0].lower() in fields:
            tokens += words[1:]
    if not decimal_comma(tokens):
        return text, False
    return text.replace(",", "."), True


def _split_lines(text: str) -> list[str]:
    # CRLF lines keep their '\r', which every check below strips as whitespace
    return normalise_newlines(text).split("\n")


# ---------------------------------------------------------------------------------------- ASF


def _floats(tokens: list[str], count: int, *, what: str, line: int) -> tuple[float, ...]:
    if len(tokens) != count:
        raise ParseError(f"{what} needs {count} numbers, found {len(tokens)}", line=line)
    return tuple(parse_float(t, what=what, line=line) for t in tokens)


def _vector(tokens: list[str], *, what: str, line: int) -> tuple[float, float, float]:
    x, y, z = _floats(tokens, 3, what=what, line=line)
    return (x, y, z)


def _parse_asf(lines: list[str], limits: ParseLimits) -> _Asf:
    asf = _Asf()
    section: str | None = None
    seen_sections: dict[str, int] = {}
    bone: _Bone | None = None
    hierarchy_state = "none"  # none -> open -> closed
    hierarchy_lines: list[tuple[int, list[str]]] = []

    for number, raw in enumerate(lines, start=1):
        if number % LINES_PER_CLOCK_CHECK == 0:
            limits.check_time()
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        tokens = line.split()
        key = tokens[0].lower()
        if key.startswith(":"):
            if bone is not None:
                raise ParseError(
                    f"bone block begun on line {bone.line} has no 'end' before {tokens[0]}",
                    line=number,
                )
            if hierarchy_state == "open":
                raise ParseError(f":hierarchy has no 'end' before {tokens[0]}", line=number)
            if key in seen_sections and key in (":units", ":root", ":bonedata", ":hierarchy"):
                raise ParseError(
                    f"second {key} section (first on line {seen_sections[key]})", line=number
                )
            seen_sections.setdefault(key, number)
            section = key
            if key == ":name" and len(tokens) > 1:
                asf.name = " ".join(tokens[1:])
            continue
        if section is None:
            raise ParseError(
                f"not an ASF file: expected a ':' section keyword, found {show(tokens[0])}",
                line=number,
            )
        if section == ":units":
            _read_unit(asf, tokens, number)
        elif section == ":root":
            _read_root_field(asf, tokens, number)
        elif section == ":bonedata":
            if key == "begin":
                if bone is not None:
                    raise ParseError(
                        f"'begin' inside the bone block begun on line {bone.line}", line=number
                    )
                bone = _Bone(name="", line=number)
            elif key == "end":
                if bone is None:
                    raise ParseError("'end' without 'begin' in :bonedata", line=number)
                _finish_bone(asf, bone, number, limits)
                bone = None
            elif bone is None:
                raise ParseError(
                    f"expected 'begin' in :bonedata, found {show(tokens[0])}", line=number
                )
            else:
                _read_bone_field(asf, bone, tokens, number)
        elif section == ":hierarchy":
            if key == "begin" and hierarchy_state == "none":
                hierarchy_state = "open"
            elif key == "end" and hierarchy_state == "open":
                hierarchy_state = "closed"
            elif hierarchy_state == "open":
                hierarchy_lines.append((number, tokens))
            else:
                raise ParseError(
                    f"unexpected {show(tokens[0])} in :hierarchy (outside begin/end)",
                    line=number,
                )
        # any other section (:version, :name, :documentation, ...) is skipped

    end = len(lines)
    if bone is not None:
        raise ParseError(f"bone block begun on line {bone.line} has no 'end'", line=end)
    if hierarchy_state == "open":
        raise ParseError(":hierarchy has no 'end'", line=end)
    for required in (":root", ":bonedata"):
        if required not in seen_sections:
            raise ParseError(f"not an ASF file: no {required} section")
    if asf.bones and hierarchy_state == "none":
        raise ParseError("no :hierarchy section: bones are not connected")
    _link_hierarchy(asf, hierarchy_lines)
    return asf


def _read_unit(asf: _Asf, tokens: list[str], number: int) -> None:
    key = tokens[0].lower()
    if len(tokens) != 2:
        raise ParseError(f":units {tokens[0]} needs one value", line=number)
    # A unit's name ("kg", "m") where the format has a number (the multiplier).
    if key == "mass" and tokens[1].isalpha():
        pass  # the mass is read by no one
    elif key == "length" and tokens[1].isalpha():
        # A writer that names the unit ("m") instead of giving the multiplier: the lengths
        # are read as written (a person's proportions do not depend on them).
        asf.warnings.append(
            f"ASF line {number}: :units length {show(tokens[1])} names a unit where the "
            "format has a number (the length multiplier): lengths read as written"
        )
    elif key in ("mass", "length"):
        value = parse_float(tokens[1], what=f":units {key}", line=number)
        if value <= 0:
            raise ParseError(f":units {key} must be greater than 0", line=number)
        if key == "length":
            asf.length_multiplier = value
    elif key == "angle":
        unit = _ANGLE_UNITS.get(tokens[1].lower())
        if unit is None:
            raise ParseError(
                f"unknown angle unit {show(tokens[1])} (expected deg or rad)", line=number
            )
        asf.angle_unit = unit
    else:
        raise ParseError(
            f"unknown :units keyword {show(tokens[0])} (expected mass, length or angle)",
            line=number,
        )


def _read_root_field(asf: _Asf, tokens: list[str], number: int) -> None:
    key = tokens[0].lower()
    if key == "order":
        order = [t.lower() for t in tokens[1:]]
        for token, dof in zip(tokens[1:], order, strict=True):
            if dof not in _ROOT_DOFS:
                raise ParseError(
                    f"unknown :root order entry {show(token)} (expected TX TY TZ RX RY RZ)",
                    line=number,
                )
        if len(set(order)) != len(order):
            raise ParseError(":root order lists an entry twice", line=number)
        asf.root.dof = order
    elif key == "axis":
        if len(tokens) != 2 or _AXIS_RE.fullmatch(tokens[1]) is None:
            raise ParseError(":root axis needs three of X, Y, Z (e.g. XYZ)", line=number)
        asf.root.axis_order = tokens[1].upper()
    elif key == "position":
        asf.root_position = _vector(tokens[1:], what=":root position", line=number)
    elif key == "orientation":
        asf.root_orientation = _vector(tokens[1:], what=":root orientation", line=number)
    else:
        raise ParseError(f"unknown :root field {show(tokens[0])}", line=number)


def _read_bone_field(asf: _Asf, bone: _Bone, tokens: list[str], number: int) -> None:
    key = tokens[0].lower()
    if key == "name":
        if len(tokens) != 2:
            raise ParseError("bone name must be one word", line=number)
        bone.name = tokens[1]
    elif key == "direction":
        direction = np.array(_vector(tokens[1:], what="bone direction", line=number))
        norm = float(np.linalg.norm(direction))
        # The format's direction is a unit vector; a writer that puts the bone's offset
        # there (and its norm under ``length``) means the same direction.
        if norm > 0 and abs(norm - 1.0) > _UNIT_TOLERANCE:
            direction = direction / norm
        bone.direction = (float(direction[0]), float(direction[1]), float(direction[2]))
    elif key == "length":
        (length,) = _floats(tokens[1:], 1, what="bone length", line=number)
        if length < 0:
            raise ParseError("bone length must not be negative", line=number)
        bone.length = length
    elif key == "axis":
        if len(tokens) != 5 or _AXIS_RE.fullmatch(tokens[4]) is None:
            raise ParseError("bone axis needs three angles and an order such as XYZ", line=number)
        bone.axis_angles = _vector(tokens[1:4], what="bone axis", line=number)
        bone.axis_order = tokens[4].upper()
    elif key == "dof":
        dof = [t.lower() for t in tokens[1:]]
        for token, name in zip(tokens[1:], dof, strict=True):
            if name not in _BONE_DOFS:
                raise ParseError(
                    f"unknown dof {show(token)} (expected rx ry rz tx ty tz l)", line=number
                )
        if len(set(dof)) != len(dof):
            raise ParseError("dof lists an entry twice", line=number)
        bone.dof = dof
    elif key in _IGNORED_BONE_FIELDS or key.startswith("("):
        pass  # limits continue on lines starting with '('
    else:
        raise ParseError(f"unknown bone field {show(tokens[0])}", line=number)


def _finish_bone(asf: _Asf, bone: _Bone, number: int, limits: ParseLimits) -> None:
    if not bone.name:
        raise ParseError(f"bone begun on line {bone.line} has no name", line=number)
    if bone.name == "root" or bone.name in asf.bones:
        raise ParseError(f"duplicate bone name {bone.name!r}", line=number)
    if bone.direction is None or bone.length is None:
        raise ParseError(f"bone {bone.name!r} needs a direction and a length", line=number)
    # Every bone is a joint; refuse early so hostile files cannot make us read on.
    if limits.max_joints is not None and len(asf.bones) + 1 >= limits.max_joints:
        raise LimitExceeded(f"ASF line {number}: more joints than the limit of {limits.max_joints}")
    asf.bones[bone.name] = bone


def _link_hierarchy(asf: _Asf, hierarchy_lines: list[tuple[int, list[str]]]) -> None:
    """Set parents and children from ``:hierarchy`` lines (read after all bones are known)."""
    for number, tokens in hierarchy_lines:
        parent_name = tokens[0]
        parent = asf.root if parent_name == "root" else asf.bones.get(parent_name)
        if parent is None:
            raise ParseError(
                f":hierarchy names unknown bone {show(parent_name)} as a parent", line=number
            )
        if len(tokens) < 2:
            raise ParseError(f":hierarchy line for {parent_name!r} lists no children", line=number)
        for child_name in tokens[1:]:
            child = asf.bones.get(child_name)
            if child is None:
                raise ParseError(
                    f":hierarchy names unknown bone {show(child_name)} as a child", line=number
                )
            if child.parent is not None:
                raise ParseError(
                    f"bone {child_name!r} is given two parents in :hierarchy", line=number
                )
            child.parent = parent_name
            parent.children.append(child_name)
    for bone in asf.bones.values():
        if bone.parent is None:
            raise ParseError(f"bone {bone.name!r} is not in :hierarchy", line=bone.line)


@dataclass(frozen=True)
class _JointPlan:
    """One joint of the output skeleton: a bone's start, the root, or a leaf bone's tip."""

    name: str
    parent: int
    bone: str  # the bone whose start this is ("root" for joint 0), or whose tip
    end_site: bool


def _order_joints(asf: _Asf, limits: ParseLimits) -> list[_JointPlan]:
    """Depth-first joints (``parents[j] < j``), iteratively so deep files cannot recurse."""
    joints = [_JointPlan(name="root", parent=-1, bone="root", end_site=False)]
    taken = {"root", *asf.bones}
    # stack of (bone name, parent joint index, depth); reversed so children keep file order
    stack = [(name, 0, 2) for name in reversed(asf.root.children)]
    while stack:
        name, parent, depth = stack.pop()
        bone = asf.bones[name]
        leaf = not bone.children
        if limits.max_depth is not None and depth + leaf > limits.max_depth:
            raise LimitExceeded(
                f"ASF line {bone.line}: the hierarchy is nested deeper than the limit of "
                f"{limits.max_depth}"
            )
        if limits.max_joints is not None and len(joints) + 1 + leaf > limits.max_joints:
            raise LimitExceeded(
                f"ASF line {bone.line}: more joints (including end sites) than the limit of "
                f"{limits.max_joints}"
            )
        joints.append(_JointPlan(name=name, parent=parent, bone=name, end_site=False))
        index = len(joints) - 1
        if leaf:
            end_name = f"{name}_end"
            suffix = 1
            while end_name in taken:
                suffix += 1
                end_name = f"{name}_end{suffix}"
            taken.add(end_name)
            joints.append(_JointPlan(name=end_name, parent=index, bone=name, end_site=True))
        stack.extend((child, index, depth + 1) for child in reversed(bone.children))
    if len(joints) - sum(j.end_site for j in joints) != len(asf.bones) + 1:
        reached = {j.bone for j in joints}
        lost = [name for name in asf.bones if name not in reached]
        raise ParseError(
            f"bones not connected to root (a cycle in :hierarchy?): {', '.join(lost[:10])}",
            line=asf.bones[lost[0]].line,
        )
    return joints


def _column_layout(asf: _Asf) -> dict[str, tuple[int, int]]:
    """Bone name -> (first column, count) in the ``(F, D)`` AMC value table; root first."""
    layout: dict[str, tuple[int, int]] = {}
    column = 0
    for bone in (asf.root, *asf.bones.values()):
        if bone.dof:
            layout[bone.name] = (column, len(bone.dof))
            column += len(bone.dof)
    return layout
