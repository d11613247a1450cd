"""Motion-capture file formats -> :class:`~app.motion.model.Motion`.

Public API
----------
``read_bvh(data, *, limits)``
    One BVH file (see :mod:`app.motion.formats.bvh`).
``read_asf_amc(asf, amc, *, limits, frame_time)``
    An Acclaim skeleton plus one motion of it (see :mod:`app.motion.formats.asf_amc`).

Both accept ``bytes`` (decoded as UTF-8; a UTF-8 byte-order mark is fine) or ``str`` and raise
:class:`~app.errors.ParseError` (with a 1-based line number where one applies) for anything
that is not a well-formed file, or :class:`~app.errors.LimitExceeded` when a file is over the
given :class:`~app.motion.model.ParseLimits`. They never raise anything else on bad input.
"""

from __future__ import annotations

from app.errors import ParseError
from app.motion.formats.asf_amc import DEFAULT_AMC_FRAME_TIME, parse_asf_amc
from app.motion.formats.bvh import parse_bvh
from app.motion.formats.text import DEFAULT_LIMITS
from app.motion.model import Motion, ParseLimits

__all__ = ["DEFAULT_AMC_FRAME_TIME", "decode_text", "read_asf_amc", "read_bvh"]


def decode_text(data: bytes | str, *, source: str | None = None) -> str:
    """The text of an uploaded motion file.

    Parameters
    ----------
    data:
        Raw bytes (must be UTF-8; plain ASCII is UTF-8) or already decoded text.
    source:
        What to call the file in error messages (e.g. ``"ASF"``); ``None`` for a lone file.

    Raises
    ------
    ParseError
        Not UTF-8, contains NUL bytes (a binary file), or empty / only whitespace.
    """
    if isinstance(data, bytes | bytearray | memoryview):
        raw = bytes(data)
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
            raise ParseError("the file is UTF-16 text; save it as UTF-8", source=source)
        if b"\x00" in raw:
            raise ParseError("the file contains NUL bytes: binary data, not text", source=source)
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as error:
            line = raw.count(b"\n", 0, error.start) + 1
            raise ParseError(
                f"the file is not UTF-8 text (byte 0x{raw[error.start]:02x} at offset "
                f"{error.start})",
                line=line,
                source=source,
            ) from None
    elif isinstance(data, str):
        text = data
        if "\x00" in text:
            raise ParseError(
                "the file contains NUL characters: binary data, not text", source=source
            )
    else:
        raise TypeError(f"expected bytes or str, got {type(data).__name__}")
    if text.startswith("\ufeff"):
        text = text[1:]
    if not text or text.isspace():
        raise ParseError("the file is empty", source=source)
    return text


def read_bvh(data: bytes | str, *, limits: ParseLimits = DEFAULT_LIMITS) -> Motion:
    """Read one BVH file.

    Parameters
    ----------
    data:
        The file's bytes (UTF-8) or text.
    limits:
        Upper bounds on joints, nesting depth, frames and values.

    Returns
    -------
    Motion
        ``source_format="bvh"``, ``length_unit="file units"``; ``local_rotations`` is
        ``(F, J, 3, 3)``, ``root_translation`` ``(F, 3)``, ``local_translations``
        ``(F, J, 3)`` when joints other than the root have position channels, else ``None``.

    Raises
    ------
    ParseError, LimitExceeded
    """
    text = decode_text(data)
    # ASCII bytes (most files) are read in place by the frame reader: no copy of the frames.
    raw = bytes(data) if isinstance(data, bytes | bytearray) and data.isascii() else None
    return parse_bvh(text, limits=limits, raw=raw)


def read_asf_amc(
    asf: bytes | str,
    amc: bytes | str,
    *,
    limits: ParseLimits = DEFAULT_LIMITS,
    frame_time: float = DEFAULT_AMC_FRAME_TIME,
) -> Motion:
    """Read an Acclaim skeleton (ASF) and one motion (AMC) of it.

    Parameters
    ----------
    asf, amc:
        The two files' bytes (UTF-8) or text.
    limits:
        Upper bounds on joints, nesting depth, frames and values.
    frame_time:
        Seconds per frame. AMC files do not say; the CMU database is captured at 120 fps,
        hence the default ``1/120``.

    Returns
    -------
    Motion
        ``source_format="asf/amc"``; lengths divided by the ASF ``:units length``
        multiplier (inches for CMU files); see :mod:`app.motion.formats.asf_amc`.

    Raises
    ------
    ParseError
        With ``source`` ``"ASF"`` or ``"AMC"`` saying which file is at fault.
    LimitExceeded
    """
    return parse_asf_amc(
        decode_text(asf, source="ASF"),
        decode_text(amc, source="AMC"),
        limits=limits,
        frame_time=frame_time,
    )
