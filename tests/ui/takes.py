"""Takes built from the real Bandai walk excerpt (tests/fixtures), for the browser tests that
need a long take or a body that leaves the floor, without ../shared.

Only the order of the real frames is changed (forwards, then backwards, in turn) and, for a
climb or a jump, the whole body is raised: the root joint's Y position channel (column 1, in
centimetres: the body is about 170 cm tall) gets ``rise_cm(t)`` added at time t.
"""

from __future__ import annotations

from collections.abc import Callable

from tests.motion.conftest import BANDAI_FIXTURE, fixture_text

FPS = 30  # the excerpt's frame time is 0.0333333 s
BODY_CM = 170.0  # about the excerpt's body height, for rises in body heights


def bandai_take(seconds: float, rise_cm: Callable[[float], float] | None = None) -> bytes:
    """A BVH take of ``seconds`` at 30 fps (see the module docstring)."""
    text = fixture_text(BANDAI_FIXTURE).replace("\r\n", "\n")
    head, rest = text.split("Frames:")
    lines = [line for line in rest.split("\n")[2:] if line.strip()]
    frame_time = rest.split("\n")[1]
    count = round(seconds * FPS)
    cycle = lines + lines[::-1]
    frames = []
    for i in range(count):
        values = cycle[i % len(cycle)].split()
        if rise_cm is not None:
            values[1] = f"{float(values[1]) + rise_cm(i / FPS):.4f}"
        frames.append(" ".join(values))
    return f"{head}Frames: {count}\n{frame_time}\n".encode() + "\n".join(frames).encode() + b"\n"


def climb(seconds: float = 8.0, height: float = 1.8) -> bytes:
    """A take whose body rises steadily by ``height`` body heights (steps, a ladder)."""
    return bandai_take(seconds, lambda t: height * BODY_CM * min(1.0, t / seconds))


def jump(seconds: float = 4.0, height: float = 0.9, at: float = 2.0) -> bytes:
    """A take with one jump of ``height`` body heights lasting 0.6 s, at ``at`` seconds."""

    def rise(t: float) -> float:
        phase = (t - at) / 0.6
        return height * BODY_CM * 4 * phase * (1 - phase) if 0 <= phase <= 1 else 0.0

    return bandai_take(seconds, rise)
