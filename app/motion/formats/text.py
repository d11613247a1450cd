"""What the text formats (BVH, ASF/AMC) share: numbers read as numpy reads them, refused by
their length before any pattern reads them; line ends; messages that quote a token without
echoing a hostile one whole."""

from __future__ import annotations

import math
import re
from collections.abc import Iterable

from app.errors import ParseError
from app.motion.model import ParseLimits

#: The limits used when a caller gives none (see :class:`ParseLimits` for the numbers).
DEFAULT_LIMITS = ParseLimits()

#: Characters; a longer token is not a number any exporter writes (a double round-trips in
#: 17 significant digits: ``-1.2345678901234567e-308`` is 24 characters), so it is refused by
#: its length before any pattern or float conversion reads it.
MAX_NUMBER_TOKEN = 100
#: Lines a reader walks between two looks at the clock (:meth:`ParseLimits.check_time`).
LINES_PER_CLOCK_CHECK = 4096

# One number as numpy's text reader accepts it (ASCII digits, no underscores, nan/inf words).
# Possessive quantifiers: a run of digits once read is never read again, so a failed match
# costs time linear in the token (a greedy ``\d+\.?\d*`` retried every split of a long run of
# digits followed by a letter: quadratic, 18 s at 32,000 digits, with the GIL held).
NUMBER_RE = re.compile(
    r"[+-]?+(?:(?:\d++(?:\.\d*+)?+|\.\d++)(?:[eE][+-]?+\d++)?+|nan|inf|infinity)",
    re.ASCII | re.IGNORECASE,
)


# A number written with a decimal comma (a European locale's printf), and one with a point.
_COMMA_NUMBER_RE = re.compile(r"[-+]?\d*,\d+(?:[eE][-+]?\d+)?", re.ASCII)
_POINT_NUMBER_RE = re.compile(r"[-+]?\d*\.\d+(?:[eE][-+]?\d+)?", re.ASCII)
#: Characters of a text file's beginning that :func:`decimal_comma` callers look at.
DECIMAL_COMMA_HEAD = 64 * 1024
#: The warning of a file whose decimal commas were read as points.
DECIMAL_COMMA_WARNING = (
    "numbers written with decimal commas (a locale's way): read as decimal points"
)


def decimal_comma(tokens: Iterable[str]) -> bool:
    """Whether a file's number ``tokens`` are written with decimal commas (``12,5``), as a
    tool under a European locale writes them: some are, and none has a decimal point (a
    file of points with a stray comma is not one). Tokens too long to be a number are not
    looked at."""
    short = [t for t in tokens if len(t) <= MAX_NUMBER_TOKEN]
    if not any(_COMMA_NUMBER_RE.fullmatch(t) for t in short):
        return False
    return not any(_POINT_NUMBER_RE.fullmatch(t) for t in short)


# The first line of a Git LFS pointer file (the LFS spec; "hawser" was its first name).
_LFS_POINTER_STARTS = (
    b"version https://git-lfs.github.com/spec/",
    b"version https://hawser.github.com/spec/",
)


def refuse_lfs_pointer(data: bytes | str, kind: str) -> None:
    """:class:`ParseError` when ``data`` is a Git LFS pointer (a few lines naming a file
    kept elsewhere, which a repository without LFS hands out in its place) rather than the
    ``kind`` file itself (any format: a pointer is what a clone gives for every large file)."""
    head = data[:64].encode("ascii", "replace") if isinstance(data, str) else bytes(data[:64])
    if head.lstrip(b"\xef\xbb\xbf").startswith(_LFS_POINTER_STARTS):
        raise ParseError(
            f"the file is a Git LFS pointer (a short text naming where the real file is kept), "
            f"not the {kind} itself: fetch the real file (git lfs pull) and upload that"
        )


def show(token: str, limit: int = 40) -> str:
    """``repr`` of a token from a file, shortened so a hostile token cannot flood a message."""
    if len(token) > limit:
        return repr(token[:limit]) + "..."
    return repr(token)


def normalise_newlines(text: str) -> str:
    """``text`` with lone ``\\r`` line ends turned into ``\\n``.

    CRLF files are left alone (copying megabytes costs milliseconds): every reader here
    splits lines on ``\\n`` and treats a trailing ``\\r`` as whitespace.
    """
    if "\r" in text and text.count("\r") != text.count("\r\n"):
        return text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def number_problem(token: str) -> str | None:
    """Why ``token`` is not a number as numpy reads one, or ``None``. Its length is checked
    first: no pattern ever reads more than :data:`MAX_NUMBER_TOKEN` characters."""
    if len(token) > MAX_NUMBER_TOKEN:
        return f"is not a number (longer than {MAX_NUMBER_TOKEN} characters)"
    if NUMBER_RE.fullmatch(token) is None:
        return "is not a number"
    return None


def parse_float(token: str, *, what: str, line: int | None) -> float:
    """A finite float from one token, or :class:`ParseError` naming ``what`` and the line."""
    problem = number_problem(token)
    if problem is not None:
        raise ParseError(f"{what}: {show(token)} {problem}", line=line)
    value = float(token)
    if not math.isfinite(value):
        raise ParseError(f"{what}: {show(token)} is not a finite number", line=line)
    return value
