"""The MOTION block of a BVH file: ``Frames:`` lines of numbers -> an ``(F, C)`` table.

One call of a C text reader reads the common layout: polars' CSV reader (one space between
numbers; twice as fast as numpy's, whose float conversion is most of a clip's parse), else
numpy's. Only when that fails or the counts disagree does a slower Python pass walk the
block line by line, to repair what a tool's export commonly damages (a short last frame, a
trailer) and to name the exact offending line otherwise. Both readers round every number
correctly, so they give the same bits.
"""

from __future__ import annotations

import contextlib
import functools
import io
import math
import re
from typing import Any

import numpy as np

from app.errors import ParseError
from app.motion.formats.text import DEFAULT_LIMITS, LINES_PER_CLOCK_CHECK, number_problem, show
from app.motion.model import ParseLimits


def read_frames(
    text: str,
    start: int,
    first_line: int,
    frame_count: int,
    frames_line: int,
    channel_count: int,
    limits: ParseLimits = DEFAULT_LIMITS,
    raw: bytes | None = None,
) -> tuple[np.ndarray, list[str]]:
    """The ``(F, C)`` frame values from ``text[start:]`` and warnings about repairs.

    Fast path: exactly ``Frames:`` lines of finite numbers, read by a C reader
    (:func:`read_spaced_numbers` from ``raw``, the file's bytes when they are ASCII and
    ``text`` is their decoding, so offsets agree; else numpy's). Otherwise
    :func:`_frame_lines` walks the block line by line (see its rules).
    """
    end = _content_end(text, start)
    # Counting lines first bounds the C reader's work by the header (no max_rows: numpy
    # warns when a blank line meets max_rows) and sends blank or extra lines to the slow pass.
    if end > start and text.count("\n", start, end) + 1 == frame_count:
        values = None
        if raw is not None and end - start >= IN_PLACE_BYTES:  # the file's bytes, in place
            values = read_spaced_numbers(raw, start, end, frame_count, channel_count)
        elif text.isascii():
            encoded = text[start:end].encode("ascii")
            values = read_spaced_numbers(encoded, 0, len(encoded), frame_count, channel_count)
            del encoded
        if values is None:
            block = text[start:end]
            if block.isascii():  # numpy's C reader is given ASCII only (see below)
                with contextlib.suppress(ValueError):
                    values = np.loadtxt(
                        io.StringIO(block), dtype=np.float64, comments=None, ndmin=2
                    )
            del block
        if (
            values is not None
            and values.shape == (frame_count, channel_count)
            and np.isfinite(values).all()
        ):
            return values, []
    limits.check_time()  # each C reader above reads the block once: bounded by its size
    lines, warnings = _frame_lines(
        text[start:end], first_line, frame_count, frames_line, channel_count, limits
    )
    block = "\n".join(lines)
    if not block.isascii():
        # Every token is an ASCII number (the line pass checked); only whitespace is not.
        # numpy's C reader is given ASCII only: it crashed the process on a fuzzed file
        # with characters beyond the BMP (app/motion/formats/amc.py, _read_regular_amc).
        block = "\n".join(" ".join(line.split()) for line in lines)
    try:
        values = np.loadtxt(io.StringIO(block), dtype=np.float64, comments=None, ndmin=2)
    except ValueError as error:  # the line pass is stricter than numpy's reader
        raise ParseError(f"the frame data could not be read ({error})", line=first_line) from None
    if values.shape != (len(lines), channel_count):
        raise ParseError(
            f"the frame data could not be read (read {values.shape[0]} x {values.shape[1]})",
            line=first_line,
        )
    missing = np.isnan(values)
    if missing.any():
        values = _fill_missing(values, missing)
        warnings.append(
            f"{int(missing.sum())} values written as nan in {int(missing.any(axis=1).sum())} "
            "frames were filled in from the neighbouring frames"
        )
    return values, warnings


def _content_end(text: str, start: int) -> int:
    """Index just past the last non-whitespace character of ``text[start:]`` (``start`` if
    none), found from the end in chunks: trailing whitespace costs its own length, and no
    copy of the text is made."""
    end = len(text)
    while end > start:
        chunk = text[max(start, end - 4096) : end]
        kept = len(chunk.rstrip())
        if kept:
            return end - len(chunk) + kept
        end -= len(chunk)
    return start


#: Frame blocks from this size up are read from the file's own bytes, in place; a smaller
#: one is copied first (a copy this size is under 1 % of one upload's memory budget, and
#: the copied read is the one measured on the dev sets: bench/README.md).
IN_PLACE_BYTES = 8 * 1024 * 1024

#: Characters per number (with its space) up to which polars reads the frame block.
MAX_NUMBER_CHARACTERS = 32


def read_spaced_numbers(
    data: bytes, start: int, end: int, rows: int, columns: int
) -> np.ndarray | None:
    """``(rows, columns)`` numbers of ``data[start:end]`` by polars' CSV reader, or ``None``
    when that range is not ``rows`` lines of ``columns`` ASCII fields separated by single
    spaces (one space at a line's end is fine) or polars is missing: the caller then uses
    numpy's.

    ``data`` is ASCII and ``start`` the first byte of a line; polars skips the lines before it
    and stops after ``rows`` lines, so the range is read in place, never copied (the caller
    has checked that it holds exactly ``rows`` lines and only whitespace follows it).

    polars parses numbers as numpy does (tested, also the tokens both refuse); quoting is
    off, so no token means more to it than to numpy. ``nan``/``inf`` come back as they are,
    and so do short lines, as ``nan`` (the caller checks). Imported at the first call
    (~0.15 s once per process).
    """
    if end - start > rows * columns * MAX_NUMBER_CHARACTERS:
        return None  # numbers this long are not the common layout (nor a hostile line's)
    try:
        import polars
    except ImportError:
        return None
    # polars takes the number of fields from the first line; a space at its end is one more,
    # empty, field (the others may end with one or not).
    first_end = data.find(b"\n", start, end)
    first_end = end if first_end < 0 else first_end
    if first_end == start:
        return None  # nothing, or a blank first line
    trailing = data[first_end - 1] == ord(" ")
    try:
        frame = polars.read_csv(
            data,
            separator=" ",
            has_header=False,
            quote_char=None,
            schema=_polars_schema(columns + trailing),
            skip_lines=data.count(b"\n", 0, start),
            n_rows=rows,
        )
    except Exception:
        return None
    except BaseException as error:  # a Rust panic inside polars is a BaseException
        if isinstance(error, KeyboardInterrupt | SystemExit | GeneratorExit):
            raise
        return None
    if frame.shape != (rows, columns + trailing):
        return None
    # null (an empty or missing field) -> nan; one row-major copy, the frame then freed
    values = frame.to_numpy(order="c").astype(np.float64, copy=False)
    del frame
    if trailing and not np.isnan(values[:, columns]).all():
        return None
    # A view without the empty trailing field: every reader of the table indexes columns.
    return values[:, :columns]


@functools.lru_cache(maxsize=64)
def _polars_schema(columns: int) -> Any:
    import polars

    return {f"c{i}": polars.Float64 for i in range(columns)}


#: A NaN as C runtimes of Visual Studio before 2015 printed it (``1.#QNAN0``, ``-1.#IND00``,
#: ``1.#SNAN``): missing data like ``nan``. Their ``1.#INF`` stays "not a number" (an
#: infinite value is damage either way).
_MSVC_NAN = re.compile(r"(?<!\S)[-+]?\d\.#(?:QNAN|SNAN|IND)\d*(?!\S)", re.IGNORECASE)

#: A declared frame count is accepted when at least this share of its frames is complete.
MIN_COMPLETE_SHARE = 0.9
#: At most this many broken lines after the last complete frame are ignored as a tool's
#: trailer or a cut (a download cut short); more, or complete frames after them, is damage.
MAX_TRAILING_LINES = 5


def _frame_lines(
    block: str,
    first_line: int,
    frame_count: int,
    frames_line: int,
    channel_count: int,
    limits: ParseLimits = DEFAULT_LIMITS,
) -> tuple[list[str], list[str]]:
    """The frame lines to read, and warnings; raises :class:`ParseError` for real damage.

    ``Frames:`` is a claim, not a contract: lines beyond the declared count are ignored; a
    last frame cut short and a few short lines a tool appended are dropped; fewer complete
    frames than declared are accepted down to :data:`MIN_COMPLETE_SHARE` of the claim. A
    broken line *between* complete frames, a non-number or an infinite value is damage and
    named by its line. ``nan`` values are missing data (filled in by the caller).
    """
    complete: list[str] = []
    trailing: list[tuple[int, str]] = []  # (line number, problem) of broken lines at the end
    extra = short_extra = 0
    for number, line in enumerate(block.split("\n"), start=first_line):
        if number % LINES_PER_CLOCK_CHECK == 0:
            limits.check_time()
        if "#" in line:  # old MSVC runtimes print a NaN as 1.#QNAN0 or -1.#IND00
            line = _MSVC_NAN.sub("nan", line)
        # maxsplit keeps a hostile 10 MB line from becoming millions of tokens
        tokens = line.split(None, channel_count)
        if not tokens:
            continue
        if len(complete) >= frame_count:
            if len(tokens) == channel_count:
                extra += 1
            else:
                short_extra += 1
            continue
        problem = _frame_line_problem(tokens, line, channel_count)
        if problem is None:
            if trailing:  # a complete frame after a broken one: the broken one is damage
                raise ParseError(trailing[0][1], line=trailing[0][0])
            complete.append(line)
            continue
        if problem.startswith("!"):  # never tolerated (not a number, not finite)
            raise ParseError(problem[1:], line=number)
        trailing.append((number, problem))
        if len(trailing) > MAX_TRAILING_LINES:
            raise ParseError(trailing[0][1], line=trailing[0][0])

    warnings: list[str] = []
    if extra:
        warnings.append(
            f"{extra} line{'s' if extra > 1 else ''} after the {frame_count} frames that "
            "Frames: declares ignored"
        )
    if short_extra or len(trailing) > 1:
        count = short_extra + len(trailing)
        warnings.append(
            f"{count} short line{'s' if count > 1 else ''} after the last frame ignored"
        )
    elif trailing:
        warnings.append(f"the last frame (line {trailing[0][0]}) was cut short: dropped")
    if len(complete) < frame_count:
        where = f" (line {trailing[0][0]}: {trailing[0][1]})" if trailing else ""
        if len(complete) < MIN_COMPLETE_SHARE * frame_count or not complete:
            raise ParseError(
                f"Frames: says {frame_count} but the file has {len(complete)} complete frame "
                f"lines{where}; at least {MIN_COMPLETE_SHARE:.0%} of the declared frames "
                "are needed",
                line=frames_line,
            )
        if len(complete) + len(trailing) < frame_count:  # else the cut says it all
            warnings.append(
                f"Frames: says {frame_count} but the file has {len(complete)} complete "
                f"frames; read {len(complete)}"
            )
    return complete, warnings


def _frame_line_problem(tokens: list[str], line: str, channel_count: int) -> str | None:
    """None for a complete frame line, else why not (``"!"`` first: never tolerated)."""
    if len(tokens) > channel_count:
        # an exact count only when it is cheap to make
        found = len(line.split()) if len(line) < 1_000_000 else f"more than {channel_count}"
        return (
            f"frame line has {found} values, more than the {channel_count} channels "
            "the hierarchy declares"
        )
    for column, token in enumerate(tokens, start=1):
        problem = number_problem(token)
        if problem is not None:
            return f"!value {column} of the frame line, {show(token)}, {problem}"
        if math.isinf(float(token)):
            return f"!value {column} of the frame line, {show(token)}, is not finite"
    if len(tokens) < channel_count:
        return f"frame line has {len(tokens)} values, expected {channel_count} (one per channel)"
    return None


def _fill_missing(values: np.ndarray, missing: np.ndarray) -> np.ndarray:
    """``values`` with nan entries interpolated along frames per channel (held at the ends).

    Raises ParseError when a channel has no number in any frame, or nan in more than half.
    """
    frames = np.arange(values.shape[0])
    out = values.copy()
    for column in np.flatnonzero(missing.any(axis=0)):
        gaps = missing[:, column]
        if gaps.sum() * 2 > len(gaps):
            raise ParseError(
                f"channel {column + 1} of the frame lines is nan in {int(gaps.sum())} of "
                f"{len(gaps)} frames: too little data to fill in"
            )
        out[gaps, column] = np.interp(frames[gaps], frames[~gaps], values[~gaps, column])
    return out


#: Rotations built per call of :func:`matrices_from_euler`: its temporaries (a few times
#: 72 bytes per rotation) stay in the CPU cache and never add to an upload's peak memory.
