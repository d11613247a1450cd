"""Cutting a file to some of its frames, as text: every kept number stays as it was written.

* :func:`cut_bvh` keeps the hierarchy as it is, corrects ``Frames:`` and keeps only the frame
  lines ``[first, stop)``;
* :func:`cut_amc` keeps the header lines (comments, ``:FULLY-SPECIFIED``, ``:DEGREES``) and
  the frames ``[first, stop)``, renumbered from 1.

Frames are counted from 0 in file order (the frame number written in an AMC does not
matter). Both expect a file the parsers read (the service only cuts stored clips); a file
whose frames cannot be told apart raises :class:`~app.errors.ParseError`.
"""

from __future__ import annotations

import re

from app.errors import ParseError
from app.motion.formats.text import normalise_newlines

_FRAME_NUMBER_RE = re.compile(r"\d+")


def _check_range(first: int, stop: int, frame_count: int) -> None:
    if not 0 <= first < stop <= frame_count:
        raise ValueError(f"frames [{first}, {stop}) are not within the file's {frame_count}")


def cut_bvh(text: str, first: int, stop: int) -> str:
    """The BVH ``text`` with only frames ``[first, stop)``."""
    lines = normalise_newlines(text).split("\n")
    motion = next((i for i, line in enumerate(lines) if line.strip().upper() == "MOTION"), None)
    if motion is None:
        raise ParseError("no MOTION section")
    header = [i for i in range(motion + 1, len(lines)) if lines[i].strip()][:2]
    if len(header) < 2 or not lines[header[0]].strip().upper().startswith("FRAMES"):
        raise ParseError("expected 'Frames:' and 'Frame Time:' after MOTION", line=motion + 1)
    frames = [line for line in lines[header[1] + 1 :] if line.strip()]
    _check_range(first, stop, len(frames))
    return "\n".join(
        [
            *lines[: motion + 1],
            f"Frames: {stop - first}",
            lines[header[1]].strip(),
            *(line.rstrip() for line in frames[first:stop]),
            "",
        ]
    )


def cut_amc(text: str, first: int, stop: int) -> str:
    """The AMC ``text`` with only frames ``[first, stop)``, renumbered from 1."""
    lines = normalise_newlines(text).split("\n")
    header: list[str] = []
    frames: list[list[str]] = []
    for line in lines:
        stripped = line.strip()
        if _FRAME_NUMBER_RE.fullmatch(stripped) is not None:
            frames.append([])
        elif not frames:
            header.append(line.rstrip())
        elif stripped and not stripped.startswith("#"):
            frames[-1].append(line.rstrip())
    _check_range(first, stop, len(frames))
    out = [line for line in header if line.strip()]
    for number, frame in enumerate(frames[first:stop], start=1):
        out.append(str(number))
        out.extend(frame)
    out.append("")
    return "\n".join(out)


__all__ = ["cut_amc", "cut_bvh"]
