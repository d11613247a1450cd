"""Motion-capture file formats -> :class:`~app.motion.model.Motion`.

Public API
----------
``read_bvh(data, *, limits)``
    One BVH file (see :mod:`app.motion.formats.bvh`).
``read_asf_amc(asf, amc, *, limits, frame_time)``
    An Acclaim skeleton plus one motion of it (see :mod:`app.motion.formats.asf_amc`).

Both accept ``bytes`` (decoded as UTF-8 — a byte-order mark is fine, UTF-16 with one too —, else
as Shift-JIS or Windows' Western code page: see ``decode_text``) or ``str`` and raise
:class:`~app.errors.ParseError` (with a 1-based line number where one applies) for anything
that is not a well-formed file, or :class:`~app.errors.LimitExceeded` when a file is over the
given :class:`~app.motion.model.ParseLimits`. They never raise anything else on bad input.
"""

from __future__ import annotations

from app.errors import ParseError
from app.motion.formats.asf_amc import DEFAULT_AMC_FRAME_TIME, parse_asf_amc
from app.motion.formats.bvh import parse_bvh
from app.motion.formats.text import DEFAULT_LIMITS, refuse_lfs_pointer
from app.motion.model import Motion, ParseLimits

__all__ = ["DEFAULT_AMC_FRAME_TIME", "decode_text", "decoded_text", "read_asf_amc", "read_bvh"]


def decode_text(data: bytes | str, *, source: str | None = None) -> str:
    """The text of an uploaded motion file (:func:`decoded_text` without its note)."""
    return decoded_text(data, source=source)[0]


def decoded_text(data: bytes | str, *, source: str | None = None) -> tuple[str, str | None]:
    """The text of an uploaded motion file, and a warning when it was not UTF-8.

    Parameters
    ----------
    data:
        Raw bytes (UTF-8, or UTF-16 with its byte-order mark; other bytes as Shift-JIS or
        Windows-1252, whose ASCII is the format's: only names differ) or decoded text.
    source:
        What to call the file in error messages (e.g. ``"ASF"``); ``None`` for a lone file.

    Raises
    ------
    ParseError
        Contains NUL bytes (a binary file), is empty / only whitespace, or is a Git LFS
        pointer instead of the file.
    """
    note = None
    if isinstance(data, bytes | bytearray | memoryview | str):
        try:
            refuse_lfs_pointer(data, "motion file")
        except ParseError as error:
            raise error.with_source(source) if source else error from None
    if isinstance(data, bytes | bytearray | memoryview):
        raw = bytes(data)
        if raw.startswith((b"\xff\xfe", b"\xfe\xff")):  # UTF-16 with its byte-order mark
            try:
                raw = raw.decode("utf-16").encode("utf-8")
            except UnicodeError:
                raise ParseError("the file says UTF-16 but is not", source=source) from None
            note = "the file is UTF-16 text: read as such"
        if b"\x00" in raw:
            raise ParseError("the file contains NUL bytes: binary data, not text", source=source)
        text, encoding = _decoded(raw)
        if encoding != "utf-8" and note is None:
            note = f"the file is not UTF-8: read as {encoding} (joint names may look wrong)"
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
    return text, note


# What a text file that is not UTF-8 is read as, in order. The formats' own words and
# numbers are ASCII in all of them; only joint names and comments differ: Shift-JIS (the
# Japanese tools MikuMikuDance data comes from), else Windows' Western code page, which
# gives every byte a character (names are hints: a wrong guess costs a hint, not the file).
_FALLBACK_ENCODINGS = ("cp932", "cp1252", "latin-1")


def _decoded(raw: bytes) -> tuple[str, str]:
    """The text of ``raw`` and the encoding it was read in."""
    for encoding in ("utf-8", *_FALLBACK_ENCODINGS):
        try:
            return raw.decode(encoding), encoding
        except UnicodeDecodeError:
            continue
    raise AssertionError("latin-1 decodes every byte")  # pragma: no cover


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
    text, note = decoded_text(data)
    # ASCII bytes (most files) are read in place by the frame reader: no copy of the frames.
    raw = bytes(data) if isinstance(data, bytes | bytearray) and data.isascii() else None
    return _noted(parse_bvh(text, limits=limits, raw=raw), [note])


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
    asf_text, asf_note = decoded_text(asf, source="ASF")
    amc_text, amc_note = decoded_text(amc, source="AMC")
    motion = parse_asf_amc(asf_text, amc_text, limits=limits, frame_time=frame_time)
    return _noted(motion, [asf_note and f"ASF: {asf_note}", amc_note and f"AMC: {amc_note}"])


def _noted(motion: Motion, notes: list[str | None]) -> Motion:
    """``motion`` with the decoding's warnings first among its warnings."""
    said = [note for note in notes if note]
    if said:
        before = motion.notes.get("warnings")
        motion.notes["warnings"] = [*said, *(before if isinstance(before, list) else [])]
    return motion
