"""Acclaim AMC (motion) text -> the ``(F, D)`` table of its values, one column per degree of
freedom of the skeleton's bones (see :mod:`app.motion.formats.asf_amc`, which reads the ASF
skeleton and builds the :class:`~app.motion.model.Motion`).

CMU AMC files repeat the same bone order every frame, so the fast path slices the lines into
one column of lines per bone and reads each with one numpy C call. Anything irregular (other
bone orders, comments, errors) falls back to a line-by-line pass that accepts every valid
file and names the exact line of the first problem.
"""

from __future__ import annotations

import re
from itertools import islice

import numpy as np

from app.errors import LimitExceeded, NoAnimation, ParseError
from app.motion.formats.text import LINES_PER_CLOCK_CHECK, parse_float, show
from app.motion.model import ParseLimits

# An AMC of headers and comments only: the skeleton is a rig with no animation.
_NO_FRAMES = "the AMC file has no frames: the skeleton has no animation to describe"
_FRAME_NUMBER_RE = re.compile(r"[+-]?\d{1,12}", re.ASCII)


def read_amc(
    lines: list[str],
    dofs: dict[str, list[str]],
    layout: dict[str, tuple[int, int]],
    joint_count: int,
    limits: ParseLimits,
) -> tuple[np.ndarray, int, str | None, list[str]]:
    """The values of an AMC file's lines for a skeleton whose bones (the root included) have
    the degrees of freedom ``dofs`` (name -> ``["rx", "ry", ...]``, empty for none), laid out
    in columns as ``layout`` says (name -> first column, count).

    Returns the ``(F, D)`` values, the first frame number, any header angle unit and
    warnings about repairs."""
    angle_unit: str | None = None
    start = 0
    while start < len(lines):
        line = lines[start].strip()
        if line and not line.startswith(("#", ":")):
            break
        keyword = line.upper()
        if keyword == ":DEGREES":
            angle_unit = "deg"
        elif keyword == ":RADIANS":
            angle_unit = "rad"
        start += 1
    end = len(lines)
    while end > start and not lines[end - 1].strip():
        end -= 1
    if start == end:
        raise NoAnimation(_NO_FRAMES)
    body = lines[start:end]
    body, warnings = _drop_cut_last_frame(body, start + 1, layout)
    column_count = sum(count for _, count in layout.values())
    fast = _read_regular_amc(body, layout, column_count, joint_count, limits)
    if fast is not None:
        return fast[0], fast[1], angle_unit, warnings
    values, first_frame = _read_amc_lines(
        body, start + 1, dofs, layout, column_count, joint_count, limits
    )
    return values, first_frame, angle_unit, warnings


def _drop_cut_last_frame(
    body: list[str], first_line: int, layout: dict[str, tuple[int, int]]
) -> tuple[list[str], list[str]]:
    """``body`` without a last frame cut short (a truncated download), and a warning.

    The last frame counts as cut when its lines are all whole lines of known bones except
    that bones are missing at its end or its last line is short; anything else in it is left
    for the readers to report. The first frame is never dropped.
    """
    # Only the last frame's number line matters, and that there is one before it: found from
    # the ends (matching every line of a long take was a third of reading an AMC).
    last = next((i for i in range(len(body) - 1, -1, -1) if _is_frame_number(body[i])), None)
    if last is None or not any(_is_frame_number(line) for line in islice(body, last)):
        return body, []
    entries = [line.split() for line in body[last + 1 :]]
    entries = [tokens for tokens in entries if tokens and not tokens[0].startswith("#")]
    seen = [tokens[0] for tokens in entries]
    if any(name not in layout for name in seen) or len(set(seen)) != len(seen):
        return body, []
    whole = [len(tokens) - 1 == layout[tokens[0]][1] for tokens in entries]
    if all(whole) and len(seen) == len(layout):
        return body, []
    if not all(whole[:-1]):
        return body, []
    return body[:last], [
        f"the last frame ({body[last].strip()}, line {first_line + last}) was cut short: dropped"
    ]


def _is_frame_number(line: str) -> bool:
    return _FRAME_NUMBER_RE.fullmatch(line.strip()) is not None


def _check_amc_limits(
    frame_count: int, column_count: int, joint_count: int, limits: ParseLimits, line: int
) -> None:
    problem = limits.frame_budget_problem(frame_count, column_count, joint_count)
    if problem is not None:
        raise LimitExceeded(f"AMC line {line}: {problem}")


def _read_regular_amc(
    body: list[str],
    layout: dict[str, tuple[int, int]],
    column_count: int,
    joint_count: int,
    limits: ParseLimits,
) -> tuple[np.ndarray, int] | None:
    """Fast path for files that repeat one bone order every frame; ``None`` if not regular.

    Only ASCII lines are given to numpy's C reader: a fuzzed AMC whose frame lines held
    characters beyond the BMP crashed the process inside ``np.loadtxt`` (a segmentation
    fault, about once in 60,000 reads of the same file, numpy 2.4.6; never with the same
    file made ASCII). A real AMC's frame lines are ASCII; any other goes line by line."""
    if not _is_frame_number(body[0]) or not all(map(str.isascii, body)):
        return None
    bone_order: list[str] = []
    for line in body[1:]:
        tokens = line.split(None, 1)
        if not tokens or len(bone_order) > len(layout):
            return None
        if _is_frame_number(line):
            break
        bone_order.append(tokens[0])
    if sorted(bone_order) != sorted(layout):
        return None
    period = 1 + len(bone_order)
    frame_count, remainder = divmod(len(body), period)
    if remainder:
        return None
    if limits.max_frames is not None and frame_count > limits.max_frames:
        return None  # the line-by-line pass raises at the exact line
    produced = frame_count * max(column_count, 9 * joint_count)
    if limits.max_values is not None and produced > limits.max_values:
        return None
    try:
        numbers = np.loadtxt(body[0::period], dtype=np.int64, comments=None, ndmin=1)
    except ValueError:
        return None
    if numbers.shape != (frame_count,):
        return None
    small = (numbers > -(10**12)) & (numbers < 10**12)  # no wrap-around in the difference
    if not small.all() or (frame_count > 1 and not (np.diff(numbers) == 1).all()):
        return None
    values = np.empty((frame_count, column_count))
    for slot, name in enumerate(bone_order, start=1):
        first, count = layout[name]
        # one row per frame: the bone name (checked) then its values
        row_type = np.dtype([("name", f"U{len(name) + 1}"), ("values", np.float64, (count,))])
        try:
            rows = np.loadtxt(body[slot::period], dtype=row_type, comments=None, ndmin=1)
        except ValueError:
            return None
        if rows.shape != (frame_count,) or not (rows["name"] == name).all():
            return None
        limits.check_time()  # one C read of one bone's lines per look
        values[:, first : first + count] = rows["values"].reshape(frame_count, count)
    if not np.isfinite(values).all():
        return None
    return values, int(numbers[0])


def _read_amc_lines(
    body: list[str],
    first_line: int,
    dofs: dict[str, list[str]],
    layout: dict[str, tuple[int, int]],
    column_count: int,
    joint_count: int,
    limits: ParseLimits,
) -> tuple[np.ndarray, int]:
    """Line-by-line AMC reading: any bone order, ``#`` comments; exact errors."""
    rows: list[list[float]] = []
    row: list[float] = []
    seen: set[str] = set()
    frame_number = 0
    first_frame = 0
    frame_line = 0
    no_dof_bones = {name for name, dof in dofs.items() if not dof}
    most_values = max((count for _, count in layout.values()), default=0)

    def finish_frame() -> None:
        if len(seen) != len(layout):
            missing = [name for name in layout if name not in seen]
            raise ParseError(
                f"frame {frame_number} has no values for bone {missing[0]!r}"
                + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""),
                line=frame_line,
            )
        rows.append(row)

    for number, raw in enumerate(body, start=first_line):
        if number % LINES_PER_CLOCK_CHECK == 0:
            limits.check_time()
        # maxsplit bounds the work on a hostile long line
        tokens = raw.split(None, most_values + 1)
        if not tokens or tokens[0].startswith("#"):
            continue
        if len(tokens) == 1 and _FRAME_NUMBER_RE.fullmatch(tokens[0]) is not None:
            if frame_line:
                finish_frame()
                if int(tokens[0]) != frame_number + 1:
                    raise ParseError(
                        f"frame numbers must be consecutive: expected {frame_number + 1}, "
                        f"found {tokens[0]}",
                        line=number,
                    )
            else:
                first_frame = int(tokens[0])
            frame_number = int(tokens[0])
            frame_line = number
            _check_amc_limits(len(rows) + 1, column_count, joint_count, limits, number)
            row = [0.0] * column_count
            seen = set()
            continue
        name = tokens[0]
        if not frame_line:
            raise ParseError(f"expected a frame number, found {show(name)}", line=number)
        entry = layout.get(name)
        if entry is None:
            if name in no_dof_bones:
                if len(tokens) == 1:
                    continue  # a bone without dof listed with no values: harmless
                if all(
                    parse_float(t, what=f"bone {name!r} value", line=number) == 0
                    for t in tokens[1:]
                ):
                    continue  # zeros a writer gives every bone: nothing to turn
                raise ParseError(
                    f"bone {name!r} has no dof in the ASF but the AMC gives it values",
                    line=number,
                )
            if _FRAME_NUMBER_RE.fullmatch(name) is not None:
                raise ParseError(
                    f"frame number line has extra text after {show(name)}", line=number
                )
            raise ParseError(f"bone {show(name)} is not in the ASF skeleton", line=number)
        if name in seen:
            raise ParseError(f"bone {name!r} appears twice in frame {frame_number}", line=number)
        seen.add(name)
        first, count = entry
        if len(tokens) - 1 != count:
            found = f"more than {count}" if len(tokens) - 1 > most_values else len(tokens) - 1
            raise ParseError(
                f"bone {name!r} needs {count} values ({' '.join(dofs[name])}), found {found}",
                line=number,
            )
        for k, token in enumerate(tokens[1:]):
            row[first + k] = parse_float(token, what=f"bone {name!r}", line=number)
    if not frame_line:
        raise NoAnimation(_NO_FRAMES, line=first_line)
    finish_frame()
    return np.array(rows, dtype=np.float64).reshape(len(rows), column_count), first_frame
