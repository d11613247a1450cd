"""BVH (Biovision Hierarchy) text -> :class:`~app.motion.model.Motion`.

What the numbers mean
---------------------
* ``OFFSET x y z`` is a joint's rest position relative to its parent, in the parent's frame,
  in the file's own length unit (centimetres for the Bandai files, ASF units for the CMU
  MotionBuilder conversions; BVH does not say, so ``Motion.length_unit`` is ``"file units"``).
* ``CHANNELS n name...`` lists, per joint, which values of each frame line belong to it and
  in which order. Rotation channels are Euler angles in **degrees**, applied **intrinsically
  in the listed order**: ``Zrotation Xrotation Yrotation`` means ``R = Rz(z) @ Rx(x) @ Ry(y)``
  (scipy: ``Rotation.from_euler("ZXY", [z, x, y], degrees=True)``).
* Position channels may sit on any joint. On the root they give ``Motion.root_translation``;
  elsewhere they give ``Motion.local_translations``. A position value *replaces* that
  component of the joint's ``OFFSET`` for that frame (checked on the Bandai files, whose
  non-root position channels repeat their offsets) unless the file's values are plainly
  changes from the offsets (Blender/MakeHuman exports write values near 0 where offsets are
  not; see ``_positions_are_deltas``), then they are added; components without a channel
  keep the offset.
* ``Frame Time`` is seconds per frame.
* ``End Site`` blocks become joints named ``"<parent>_end"`` with ``end_site=True`` and
  identity rotation.

Parsing strategy
----------------
The hierarchy is read line by line with an explicit stack (no recursion, so nesting depth is
bounded only by :class:`~app.motion.model.ParseLimits`). The frame block
(:mod:`app.motion.formats.bvh_frames`) is read by one call of a C text reader: polars' CSV
reader for the common layout (one space between numbers; twice as fast as numpy's, whose
float conversion is most of a clip's parse), else numpy's; only when that fails or the
counts disagree does a slower Python pass walk the block line by line to name the exact
offending line. Both readers round every number correctly, so they give the same bits.
"""

from __future__ import annotations

import itertools
import re
import string
import threading
from dataclasses import dataclass, field, replace

import numpy as np

from app.errors import LimitExceeded, NoAnimation, ParseError
from app.motion.formats.bvh_frames import read_frames
from app.motion.formats.leaf_bones import without_detached_leaves
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
from app.motion.model import Motion, ParseLimits, Skeleton

_HIERARCHY_TOKEN = re.compile(r"[{}]|[^\s{}]+")

__all__ = ["matrices_from_euler", "parse_bvh", "parse_bvh_rest"]


#: Seconds; a frame time longer than this is taken as a broken header, not a slow clip.
MAX_FRAME_TIME = 10.0
#: Seconds; a frame time shorter than this (100,000 frames per second) is no capture rate,
#: and would turn every small step into a speed past float32 in the descriptors.
MIN_FRAME_TIME = 1e-5
#: Characters; hierarchy lines are short, a longer one is garbage (keeps token lists small).
MAX_HIERARCHY_LINE = 65_536

_INTEGER_RE = re.compile(r"\+?\d+", re.ASCII)
_SIGNED_INTEGER_RE = re.compile(r"[+-]?\d+", re.ASCII)
# The colon as writers put it, or leave it out or write ``=`` (``Frame Time 0.0333``,
# ``FrameTime: 0.0333``, ``Frame Times: 0.0333``): the words say what the number is.
_FRAMES_RE = re.compile(r"frames\s*[:=]?\s*(.*)", re.IGNORECASE)
_FRAME_TIME_RE = re.compile(r"frame\s*times?\s*[:=]?\s*(.*)", re.IGNORECASE)

# channel name (lower case) -> (kind, axis index)
_CHANNELS: dict[str, tuple[str, int]] = {
    "xposition": ("position", 0),
    "yposition": ("position", 1),
    "zposition": ("position", 2),
    "xrotation": ("rotation", 0),
    "yrotation": ("rotation", 1),
    "zrotation": ("rotation", 2),
}
_AXIS_LETTERS = "XYZ"
# Marks that may stick to the end of a channel's name in a written file ("Zrotation#" in a
# widely shared dance capture): the name is still that channel's, read with a warning.
_STRAY_MARKS = string.punctuation


def matrices_from_euler(
    sequence: str, angles: np.ndarray, *, frames: np.ndarray | None = None
) -> np.ndarray:
    """Rotation matrices from Euler angles, vectorised, with scipy's sequence convention.

    Parameters
    ----------
    sequence:
        1 to 3 axis letters. Upper case (``"ZXY"``) means intrinsic rotations in the listed
        order, ``R = R_Z @ R_X @ R_Y``; lower case (``"xyz"``) means extrinsic rotations in the
        listed order, ``R = R_z @ R_y @ R_x``. Same meaning as
        ``scipy.spatial.transform.Rotation.from_euler``.
    angles:
        ``(..., len(sequence))`` angles in **radians**, in the order of ``sequence``.
    frames:
        Optional ``(..., 3, 3)`` rotations ``C`` broadcastable against the batch shape of
        ``angles``. When given, the result is ``C @ R @ C.T``: the rotation ``R`` about the
        axes of frame ``C`` (how ASF bones rotate about their ``axis``).

    Returns
    -------
    numpy.ndarray
        ``(..., 3, 3)`` float64 matrices acting on column vectors.

    Notes
    -----
    About 8x faster than ``Rotation.from_euler(...).as_matrix()`` (measured on 5 000 and
    50 000 rotations): each elementary rotation only mixes two columns, so the product is
    built by updating columns in place instead of multiplying full matrices. With ``frames``
    it is about 2x faster than two batched ``@`` products.
    """
    angles = np.asarray(angles, dtype=np.float64)
    if sequence.islower():
        # Extrinsic a, b, c == intrinsic c, b, a.
        sequence = sequence[::-1].upper()
        angles = angles[..., ::-1]
    cosines = np.cos(angles)
    sines = np.sin(angles)
    batch = angles.shape[:-1]
    # Built as (3, 3, ...) so every column update touches contiguous memory.
    if frames is None:
        matrix = np.zeros((3, 3, *batch))
        matrix[0, 0] = matrix[1, 1] = matrix[2, 2] = 1.0
    else:
        frames = np.asarray(frames, dtype=np.float64)
        batch = np.broadcast_shapes(batch, frames.shape[:-2])
        frames_first = np.moveaxis(np.broadcast_to(frames, (*batch, 3, 3)), (-2, -1), (0, 1))
        matrix = np.array(frames_first)  # starts as C
    for i, letter in enumerate(sequence):
        a = _AXIS_LETTERS.index(letter)
        b, d = (a + 1) % 3, (a + 2) % 3
        cos_i, sin_i = cosines[..., i], sines[..., i]
        # matrix @ R_a(angle): column b <- c*b + s*d, column d <- c*d - s*b
        column_b = matrix[:, b].copy()
        column_d = matrix[:, d]
        matrix[:, b] = column_b * cos_i + column_d * sin_i
        matrix[:, d] = column_d * cos_i - column_b * sin_i
    if frames is not None:
        # (C @ R) @ C.T: column l of the product is sum_k column_k(C @ R) * C[l, k]
        product = np.empty_like(matrix)
        for row in range(3):
            product[:, row] = (
                matrix[:, 0] * frames_first[row, 0]
                + matrix[:, 1] * frames_first[row, 1]
                + matrix[:, 2] * frames_first[row, 2]
            )
        matrix = product
    return np.ascontiguousarray(np.moveaxis(matrix, (0, 1), (-2, -1)))


@dataclass
class _Joint:
    """One joint while the hierarchy is being read."""

    name: str
    parent: int
    line: int
    end_site: bool = False
    offset: tuple[float, float, float] | None = None
    # (kind, axis) per channel, in file order
    channels: list[tuple[str, int]] | None = None
    # What was read past on the joint's lines (a stray mark on a channel's name).
    notes: list[str] = field(default_factory=list)


class _Lines:
    """Iterates the lines of ``text`` from a character position, counting line numbers, and
    looks at the clock of ``limits`` every :data:`LINES_PER_CLOCK_CHECK` lines."""

    def __init__(self, text: str, limits: ParseLimits = DEFAULT_LIMITS) -> None:
        self.text = text
        self.pos = 0
        self.line = 0  # 1-based number of the line last returned
        self.limits = limits

    def next(self) -> str | None:
        """The next line without its newline, or ``None`` at the end of the text."""
        if self.pos >= len(self.text):
            return None
        if self.line % LINES_PER_CLOCK_CHECK == 0:
            self.limits.check_time()
        end = self.text.find("\n", self.pos)
        if end < 0:
            end = len(self.text)
        line = self.text[self.pos : end]
        self.pos = end + 1
        self.line += 1
        return line

    def next_nonblank(self) -> str | None:
        while (line := self.next()) is not None:
            if line.strip():
                return line
        return None


def parse_bvh(
    text: str, *, limits: ParseLimits = DEFAULT_LIMITS, raw: bytes | None = None
) -> Motion:
    """Read a BVH file already decoded to text.

    Parameters
    ----------
    text:
        The whole file. ``\\r\\n`` and ``\\r`` line ends are accepted.
    limits:
        Upper bounds on joints, nesting depth, frames and values, and the deadline.
    raw:
        The bytes ``text`` was decoded from, when they are ASCII (then ``raw.decode() ==
        text`` character for byte): the frame block is read from them in place instead of
        from a copy. Ignored unless its length is the text's.

    Returns
    -------
    Motion
        ``source_format="bvh"``; see the module docstring for what the arrays hold.

    Raises
    ------
    ParseError
        The text is not a well-formed BVH file; ``line`` says where when it applies.
    LimitExceeded
        The file is over one of ``limits``.
    """
    limits.check_time()
    normalised = normalise_newlines(text)
    if raw is not None and (normalised is not text or len(raw) != len(text)):
        raw = None  # line ends were rewritten: the bytes are not the text any more
    text = normalised
    commas = _decimal_comma(text)
    if commas:
        text, raw = text.replace(",", "."), None
    lines = _Lines(text, limits)
    joints = _HIERARCHIES.read(lines, limits)
    frame_count, frames_line, frame_time = _read_motion_header(lines, len(joints))

    channel_count = sum(len(j.channels or ()) for j in joints)
    if channel_count == 0:
        raise ParseError("the hierarchy declares no CHANNELS, so frames hold no data")
    _check_frame_limits(frame_count, channel_count, len(joints), limits)
    values, warnings = read_frames(
        text, lines.pos, lines.line + 1, frame_count, frames_line, channel_count, limits, raw
    )
    marks = [note for joint in joints for note in joint.notes]
    joints, values, several = _largest_skeleton(joints, values)
    motion = _build_motion(joints, values, frame_time, limits)
    comma = DECIMAL_COMMA_WARNING
    built = motion.notes.get("warnings")  # _build_motion's own (end bones left out)
    warnings = [*([comma] if commas else []), *([several] if several else []), *marks, *warnings]
    warnings += built if isinstance(built, list) else []
    if warnings:
        motion.notes["warnings"] = warnings
    return motion


def parse_bvh_rest(text: str, *, limits: ParseLimits = DEFAULT_LIMITS) -> Motion:
    """The hierarchy of a BVH file as one frame of its rest pose, whatever its MOTION section
    holds (``Frames: 0`` included, or no MOTION section at all: a skeleton exported alone):
    a rig to retarget onto. Raises like :func:`parse_bvh`."""
    text = normalise_newlines(text)
    if _decimal_comma(text):
        text = text.replace(",", ".")
    # A whole hierarchy and nothing after it is read too: the skeleton is all a rig needs.
    joints = _HIERARCHIES.read(_Lines(text), limits, motion_optional=True)
    channel_count = sum(len(j.channels or ()) for j in joints)
    # Zero channels: no rotation, and position channels that read as "no change" from the
    # OFFSETs (see _positions_are_deltas), so the rest pose is the OFFSETs'.
    joints, values, _ = _largest_skeleton(joints, np.zeros((1, channel_count)))
    return _build_motion(joints, values, 1.0 / 30.0)


def _decimal_comma(text: str) -> bool:
    """Whether the file writes its numbers with decimal commas (``12,5``), as a tool under a
    European locale does: the OFFSETs and the first frame line hold such numbers and none
    with a decimal point. Read from the hierarchy's first 64 KB and the first frame line."""
    head = text[:DECIMAL_COMMA_HEAD]
    motion = _MOTION_LINE_RE.search(head)
    hierarchy = head[: motion.start()] if motion else head
    tokens = [t for line in hierarchy.split("\n") if "OFFSET" in line.upper() for t in line.split()]
    if motion:
        after = head[motion.end() :].split("\n")
        data = [line for line in after if line.strip()][2:3]  # past Frames: and Frame Time:
        tokens += data[0].split() if data else []
    return decimal_comma(tokens)


def _largest_skeleton(
    joints: list[_Joint], values: np.ndarray
) -> tuple[list[_Joint], np.ndarray, str | None]:
    """The skeleton of the file's several ROOTs (a second person, a prop, a camera rig) with
    the most joints (the first of equals), its ``(F, C')`` columns of the ``(F, C)`` frame
    values, and a warning naming what was left out (None for a file of one skeleton).
    Each ROOT's joints and channels follow one another in the file."""
    roots = [i for i, joint in enumerate(joints) if joint.parent < 0]
    if len(roots) == 1:
        return joints, values, None
    bounds = [*roots, len(joints)]
    sizes = [
        sum(not joint.end_site for joint in joints[a:b]) for a, b in itertools.pairwise(bounds)
    ]
    chosen = sizes.index(max(sizes))
    begin, end = bounds[chosen], bounds[chosen + 1]
    widths = [len(joint.channels or ()) for joint in joints]
    first = sum(widths[:begin])
    kept = [
        replace(joint, parent=joint.parent - begin if joint.parent >= 0 else -1)
        for joint in joints[begin:end]
    ]
    others = ", ".join(
        f"{joints[root].name!r} ({size} joints)"
        for k, (root, size) in enumerate(zip(roots, sizes, strict=True))
        if k != chosen
    )
    warning = (
        f"the file holds {len(roots)} skeletons (ROOTs); the largest, number {chosen + 1}, "
        f"{joints[begin].name!r} ({sizes[chosen]} joints), is read and {others} left out"
    )
    return kept, values[:, first : first + sum(widths[begin:end])], warning


# The line that ends the hierarchy (the parser's rule: a line whose only token is MOTION).
_MOTION_LINE_RE = re.compile(r"^[ \t\r\f\v]*motion[ \t\r\f\v]*$\n?", re.IGNORECASE | re.MULTILINE)


class _HierarchyMemo:
    """Hierarchies already read in this process, by their exact text (up to and including
    the ``MOTION`` line) and the limits they were read under: the clips of one studio share a
    rig, so an import reads each rig once. A file whose text before its first ``MOTION`` line
    differs by one character is read in full; only hierarchies that were read without error
    are kept. The joints are shared between the clips: nothing changes them after reading."""

    MAX_ENTRIES = 32
    MAX_TEXT = 128 * 1024  # characters (the largest here: 36 K); larger ones are read each time

    def __init__(self) -> None:
        self._read: dict[tuple[str, ParseLimits], tuple[list[_Joint], int]] = {}
        self._lock = threading.Lock()

    def read(
        self, lines: _Lines, limits: ParseLimits, *, motion_optional: bool = False
    ) -> list[_Joint]:
        """:func:`_read_hierarchy` of ``lines`` (from their start), remembered (only up to a
        ``MOTION`` line: ``motion_optional`` changes nothing there)."""
        found = _MOTION_LINE_RE.search(lines.text, 0, self.MAX_TEXT)
        key = None if found is None else (lines.text[: found.end()], limits)
        if key is not None:
            with self._lock:
                known = self._read.get(key)
            if known is not None:
                joints, line_count = known
                lines.pos, lines.line = found.end(), line_count  # type: ignore[union-attr]
                return joints
        joints = _read_hierarchy(lines, limits, motion_optional=motion_optional)
        if key is not None and lines.pos == found.end():  # type: ignore[union-attr]
            with self._lock:
                if len(self._read) >= self.MAX_ENTRIES:
                    self._read.pop(next(iter(self._read)))
                self._read[key] = (joints, lines.line)
        return joints


_HIERARCHIES = _HierarchyMemo()


def _read_hierarchy(
    lines: _Lines, limits: ParseLimits, *, motion_optional: bool = False
) -> list[_Joint]:
    """Read from ``HIERARCHY`` to the ``MOTION`` line; joints in depth-first file order.

    A whole hierarchy ending the file is a rig with no animation (:class:`NoAnimation`), or
    with ``motion_optional`` (a rig is wanted) simply the joints."""
    first = lines.next_nonblank()
    if first is None:
        raise ParseError("the file is empty")
    if len(first) > MAX_HIERARCHY_LINE:
        raise ParseError("not a BVH file: the first line is far too long", line=lines.line)
    if first.split()[0].upper() != "HIERARCHY":
        raise ParseError(
            f"not a BVH file: expected HIERARCHY, found {show(first.strip())}", line=lines.line
        )
    if len(first.split()) > 1:
        raise ParseError("unexpected text after HIERARCHY", line=lines.line)

    joints: list[_Joint] = []
    names: dict[str, int] = {}  # real joint name -> line it was declared on
    open_joints: list[int] = []  # stack of joints whose '{' is open
    awaiting_brace: int | None = None  # joint declared, its '{' not yet seen
    root_closed = False

    while True:
        text_line = lines.next()
        number = lines.line
        if text_line is None:
            if not joints:
                raise ParseError("the hierarchy has no ROOT joint (end of file)", line=number)
            if awaiting_brace is not None or open_joints:
                where = joints[open_joints[-1] if open_joints else awaiting_brace or 0]
                raise ParseError(
                    f"the hierarchy is truncated: end of file inside {where.name!r} "
                    f"(opened on line {where.line}); missing '}}'",
                    line=number,
                )
            if root_closed and motion_optional:
                return joints
            if root_closed:  # a whole hierarchy and nothing after it: a rig
                raise NoAnimation(
                    f"the file is a rig with no animation: a skeleton of {len(joints)} joints "
                    "and no MOTION section after it, so there is no motion to describe"
                )
            raise ParseError("MOTION section missing after the hierarchy", line=number)
        if len(text_line) > MAX_HIERARCHY_LINE:
            raise ParseError(
                f"hierarchy line is {len(text_line)} characters long; not a BVH hierarchy",
                line=number,
            )
        # A brace is a token of its own even when a writer glues it to a word
        # ("End Site{", "JOINT Hips{", "}}"), as hand-written exporters do.
        tokens = _HIERARCHY_TOKEN.findall(text_line)
        i = 0
        while i < len(tokens):
            keyword = tokens[i].upper()
            if root_closed:
                if keyword == "MOTION":
                    if len(tokens) > 1:
                        raise ParseError("unexpected text after MOTION", line=number)
                    return joints
                if keyword == "ROOT":  # another skeleton (a second person, a prop)
                    root_closed = False
                    names.clear()  # two people of one rig: a name is unique in its skeleton
                    continue
                raise ParseError(
                    f"expected MOTION after the hierarchy, found {show(tokens[i])}", line=number
                )
            if keyword == "{":
                if awaiting_brace is None:
                    raise ParseError(
                        "unexpected '{' (no ROOT, JOINT or End Site before it)", line=number
                    )
                open_joints.append(awaiting_brace)
                awaiting_brace = None
                i += 1
                continue
            if awaiting_brace is not None:
                raise ParseError(
                    f"expected '{{' after {joints[awaiting_brace].name!r}, found {show(tokens[i])}",
                    line=number,
                )
            if keyword == "}":
                if not open_joints:
                    raise ParseError("unbalanced '}'", line=number)
                closing = joints[open_joints.pop()]
                if closing.offset is None:
                    raise ParseError(f"joint {closing.name!r} has no OFFSET", line=number)
                if not closing.end_site and closing.channels is None:
                    closing.channels = []  # a joint without CHANNELS has none
                root_closed = not open_joints
                i += 1
                continue
            if keyword in ("ROOT", "JOINT", "END"):
                i, awaiting_brace = _declare_joint(
                    tokens, i, number, joints, names, open_joints, limits
                )
                continue
            if keyword == "MOTION":
                if not joints:
                    raise ParseError("MOTION before any ROOT joint", line=number)
                where = joints[open_joints[-1] if open_joints else awaiting_brace or 0]
                raise ParseError(
                    f"the hierarchy is truncated: MOTION inside {where.name!r} "
                    f"(opened on line {where.line}); missing '}}'",
                    line=number,
                )
            if not open_joints:
                raise ParseError(f"expected ROOT, found {show(tokens[i])}", line=number)
            current = joints[open_joints[-1]]
            keyword_token = tokens[i]
            arguments: list[str] = []
            i += 1
            while i < len(tokens) and tokens[i] not in ("{", "}"):
                arguments.append(tokens[i])
                i += 1
            if keyword == "OFFSET":
                _set_offset(current, arguments, number)
            elif keyword == "CHANNELS":
                _set_channels(current, arguments, number)
            else:
                raise ParseError(f"unknown keyword {show(keyword_token)}", line=number)


def _declare_joint(
    tokens: list[str],
    i: int,
    number: int,
    joints: list[_Joint],
    names: dict[str, int],
    open_joints: list[int],
    limits: ParseLimits,
) -> tuple[int, int]:
    """Handle ``ROOT name``, ``JOINT name`` or ``End Site``; returns (next token, new joint)."""
    keyword = tokens[i].upper()
    i += 1
    name_tokens: list[str] = []
    while i < len(tokens) and tokens[i] != "{":
        name_tokens.append(tokens[i])
        i += 1
    if keyword == "ROOT":
        if open_joints:
            inside = joints[open_joints[-1]].name
            raise ParseError(f"a ROOT inside the joint {inside!r}", line=number)
        parent = -1
    else:
        if not open_joints:
            what = "JOINT" if keyword == "JOINT" else "End Site"
            raise ParseError(f"{what} outside of any ROOT", line=number)
        parent = open_joints[-1]
        if joints[parent].end_site:
            raise ParseError("an End Site cannot have children", line=number)

    end_site = keyword == "END"
    if end_site:
        # "End Site" (optionally followed by a name some exporters write; ignored)
        if name_tokens and name_tokens[0].upper() == "SITE":
            name_tokens = name_tokens[1:]
        name = f"{joints[parent].name}_end"  # made unique in _build_motion
    else:
        if not name_tokens:
            raise ParseError(f"{keyword} without a name", line=number)
        name = " ".join(name_tokens)
        if name in names:
            raise ParseError(
                f"duplicate joint name {name!r} (first declared on line {names[name]})",
                line=number,
            )
        names[name] = number

    depth = len(open_joints) + 1
    if limits.max_depth is not None and depth > limits.max_depth:
        raise LimitExceeded(
            f"line {number}: the hierarchy is nested deeper than the limit of {limits.max_depth}"
        )
    if limits.max_joints is not None and len(joints) >= limits.max_joints:
        raise LimitExceeded(
            f"line {number}: more joints (including End Sites) than the limit of "
            f"{limits.max_joints}"
        )
    joints.append(_Joint(name=name, parent=parent, line=number, end_site=end_site))
    return i, len(joints) - 1


def _set_offset(joint: _Joint, arguments: list[str], number: int) -> None:
    if joint.offset is not None:
        raise ParseError(f"second OFFSET for joint {joint.name!r}", line=number)
    if len(arguments) != 3:
        raise ParseError(
            f"OFFSET of {joint.name!r} needs 3 numbers, found {len(arguments)}", line=number
        )
    x, y, z = (parse_float(a, what=f"OFFSET of {joint.name!r}", line=number) for a in arguments)
    joint.offset = (x, y, z)


def _set_channels(joint: _Joint, arguments: list[str], number: int) -> None:
    if joint.end_site:
        raise ParseError("an End Site cannot have CHANNELS", line=number)
    if joint.channels is not None:
        raise ParseError(f"second CHANNELS line for joint {joint.name!r}", line=number)
    if not arguments or _INTEGER_RE.fullmatch(arguments[0]) is None:
        found = show(arguments[0]) if arguments else "nothing"
        raise ParseError(f"CHANNELS must start with a count, found {found}", line=number)
    declared = int(arguments[0]) if len(arguments[0]) < 10 else -1
    listed = arguments[1:]
    if declared != len(listed):
        raise ParseError(
            f"CHANNELS says {arguments[0][:20]} but lists {len(listed)} channel names",
            line=number,
        )
    channels: list[tuple[str, int]] = []
    for channel_name in listed:
        channel = _CHANNELS.get(channel_name.lower())
        if channel is None:
            bare = channel_name.rstrip(_STRAY_MARKS)
            channel = _CHANNELS.get(bare.lower())
            if channel is not None:
                joint.notes.append(f"line {number}: channel {show(channel_name)} read as {bare!r}")
        if channel is None:
            raise ParseError(
                f"unknown channel {show(channel_name)} for joint {joint.name!r} "
                "(expected Xposition, Yposition, Zposition, Xrotation, Yrotation, Zrotation)",
                line=number,
            )
        if channel in channels:
            raise ParseError(f"channel {channel_name} listed twice", line=number)
        channels.append(channel)
    joint.channels = channels


def _read_motion_header(lines: _Lines, joint_count: int) -> tuple[int, int, float]:
    """Read ``Frames:`` and ``Frame Time:``; returns (frame count, its line, seconds/frame).

    ``Frames: 0`` is a rig with no animation (:class:`NoAnimation`), not a damaged file."""
    frames_line = lines.next_nonblank()
    match = None if frames_line is None else _FRAMES_RE.fullmatch(frames_line.strip())
    if frames_line is None or match is None:
        raise ParseError("expected 'Frames: <count>' after MOTION", line=lines.line)
    token = match.group(1).strip()
    if _SIGNED_INTEGER_RE.fullmatch(token) is None:
        raise ParseError(f"Frames: {show(token)} is not a whole number", line=lines.line)
    # a 10**18 stand-in for absurdly long numbers is caught by the frame limit
    frame_count = int(token) if len(token) <= 18 else (10**18 if token[0] != "-" else -1)
    if frame_count == 0:
        zero_line = lines.line
        lines.next_nonblank()  # Frame Time:, if written
        # Frames: is a claim (lines beyond it are ignored): values after a count of none
        # are not read, and the refusal says they are there.
        beyond = (
            f"; the values from line {lines.line} on are not read (Frames: says 0)"
            if lines.next_nonblank() is not None
            else ""
        )
        raise NoAnimation(
            f"Frames: 0 — the file is a rig with no animation (a skeleton of {joint_count} "
            f"joints and no frames), so there is no motion to describe{beyond}",
            line=zero_line,
        )
    if frame_count < 0:
        raise ParseError("Frames: must be at least 1", line=lines.line)
    frames_line_number = lines.line

    time_line = lines.next_nonblank()
    match = None if time_line is None else _FRAME_TIME_RE.fullmatch(time_line.strip())
    if time_line is None or match is None:
        raise ParseError("expected 'Frame Time: <seconds>' after Frames:", line=lines.line)
    frame_time = parse_float(match.group(1).strip(), what="Frame Time", line=lines.line)
    if frame_time <= 0:
        raise ParseError("Frame Time must be greater than 0 seconds", line=lines.line)
    if frame_time < MIN_FRAME_TIME:
        raise ParseError(
            f"Frame Time of {frame_time:g} s is absurd (more than {1 / MIN_FRAME_TIME:,.0f} "
            "frames per second)",
            line=lines.line,
        )
    if frame_time > MAX_FRAME_TIME:
        raise ParseError(
            f"Frame Time of {frame_time:g} s is absurd (more than {MAX_FRAME_TIME:g} s)",
            line=lines.line,
        )
    return frame_count, frames_line_number, frame_time


def _check_frame_limits(
    frame_count: int, channel_count: int, joint_count: int, limits: ParseLimits
) -> None:
    """Refuse before allocating: frames, values in the file and rotation values produced."""
    problem = limits.frame_budget_problem(frame_count, channel_count, joint_count)
    if problem is not None:
        raise LimitExceeded(problem)


ROTATIONS_PER_CHUNK = 16_384


def _build_motion(
    joints: list[_Joint],
    values: np.ndarray,
    frame_time: float,
    limits: ParseLimits = DEFAULT_LIMITS,
) -> Motion:
    """Turn joints and the ``(F, C)`` value table into a :class:`Motion`.

    The ``(F, J, 3, 3)`` rotations are written in place, a chunk of frames at a time: the
    only arrays as large as the clip are the value table and the motion's own."""
    frame_count = values.shape[0]
    joint_count = len(joints)
    names = _unique_names(joints)
    parents = np.array([j.parent for j in joints], dtype=np.int64)
    offsets = np.array([j.offset for j in joints], dtype=np.float64).reshape(joint_count, 3)
    end_site = np.array([j.end_site for j in joints], dtype=bool)

    # Column layout: rotation groups by axis sequence, position (joint, axis, column) triples.
    rotation_groups: dict[str, tuple[list[int], list[list[int]]]] = {}
    position_joint: list[int] = []
    position_axis: list[int] = []
    position_column: list[int] = []
    column = 0
    for index, joint in enumerate(joints):
        sequence = ""
        rotation_columns: list[int] = []
        for kind, axis in joint.channels or ():
            if kind == "rotation":
                sequence += _AXIS_LETTERS[axis]
                rotation_columns.append(column)
            else:
                position_joint.append(index)
                position_axis.append(axis)
                position_column.append(column)
            column += 1
        if sequence:
            group_joints, group_columns = rotation_groups.setdefault(sequence, ([], []))
            group_joints.append(index)
            group_columns.append(rotation_columns)

    rotations = np.empty((frame_count, joint_count, 3, 3))
    fixed = np.ones(joint_count, dtype=bool)
    for group_joints, _ in rotation_groups.values():
        fixed[group_joints] = False
    rotations[:, fixed] = np.eye(3)  # end sites and joints without rotation channels
    for sequence, (group_joints, group_columns) in rotation_groups.items():
        group = np.array(group_joints, dtype=np.int64)
        columns = np.array(group_columns, dtype=np.int64)
        step = max(1, ROTATIONS_PER_CHUNK // len(group))
        for start in range(0, frame_count, step):
            stop = min(start + step, frame_count)
            angles = np.radians(values[start:stop, columns])  # (chunk, G, k)
            rotations[start:stop, group] = matrices_from_euler(sequence, angles)
            limits.check_time()

    root_translation = np.repeat(offsets[None, 0], frame_count, axis=0)
    local_translations = None
    joint_index = np.array(position_joint, dtype=np.int64)
    axis_index = np.array(position_axis, dtype=np.int64)
    column_index = np.array(position_column, dtype=np.int64)
    on_root = joint_index == 0
    root_translation[:, axis_index[on_root]] = values[:, column_index[on_root]]
    if (~on_root).any():
        local_translations = np.repeat(offsets[None], frame_count, axis=0)
        channel_values = values[:, column_index[~on_root]]
        rest = offsets[joint_index[~on_root], axis_index[~on_root]]
        if _positions_are_deltas(channel_values, rest):
            channel_values = channel_values + rest
        local_translations[:, joint_index[~on_root], axis_index[~on_root]] = channel_values
        local_translations[:, 0] = root_translation

    skeleton = Skeleton(names=names, parents=parents, offsets=offsets, end_site=end_site)
    skeleton, local_translations, leaf_warning = without_detached_leaves(
        skeleton, local_translations
    )
    return Motion(
        skeleton=skeleton,
        frame_time=frame_time,
        root_translation=root_translation,
        local_rotations=rotations,
        local_translations=local_translations,
        source_format="bvh",
        length_unit="file units",
        notes={"warnings": [leaf_warning]} if leaf_warning else {},
    )


def _positions_are_deltas(values: np.ndarray, rest: np.ndarray) -> bool:
    """Whether non-root position channels hold offsets from the rest ``OFFSET`` rather than
    the offset itself.

    Exporters disagree: Bandai's and most mocap tools' non-root position channels repeat
    the OFFSET (the value replaces it), Blender-based ones (MakeHuman) write the change from
    it (values near 0 where the OFFSET is not). ``values`` is ``(F, K)`` for the K non-root
    position channels, ``rest`` ``(K,)`` their OFFSET components; whichever reading is nearer
    the numbers wins, ties (all offsets 0) reading values as replacements.
    """
    replace_error = float(np.abs(values - rest).mean())
    delta_error = float(np.abs(values).mean())
    return delta_error < 0.5 * replace_error


def _unique_names(joints: list[_Joint]) -> tuple[str, ...]:
    """Joint names with generated End Site names made unique against every other name."""
    taken = {j.name for j in joints if not j.end_site}
    tried: dict[str, int] = {}  # base name -> last suffix tried: the search never starts over
    names: list[str] = []
    for joint in joints:
        name = joint.name
        if joint.end_site:
            suffix = tried.get(joint.name, 1)
            while name in taken:
                suffix += 1
                name = f"{joint.name}{suffix}"
            tried[joint.name] = suffix
            taken.add(name)
        names.append(name)
    return tuple(names)
