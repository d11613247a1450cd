"""Hostile tokens and long reads, timed (the unit tests check what the readers do, not how
fast: tests/motion/test_bvh.py, test_asf_amc.py).

Run from the repository root::

    .venv/bin/python bench/bench_hostile_parse.py [--repeat 3]

For one invalid number (digits then a letter) in a BVH frame line, a BVH OFFSET and an AMC
value, at several token sizes: the seconds the reader takes to refuse it, and the ratio to
the smallest size. A linear reader's time grows like the token (x10, x30: splitting the
line and the C readers' one pass); the quadratic number pattern of before took 18 s at
32,000 digits and 22 minutes at 200,000.
Then the old guards that were timed unit tests: a 10 MB frame line, 300,000 lines past the
frames, 990 End Sites of one name, a million braces. The fixtures are the tests' own.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from collections.abc import Callable
from pathlib import Path

from common import machine  # bench/common.py (scripts run from bench/)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.errors import ParseError  # noqa: E402
from app.motion.formats import read_asf_amc, read_bvh  # noqa: E402
from tests.motion.test_asf_amc import M_HIP_1, TINY_AMC, TINY_ASF  # noqa: E402
from tests.motion.test_asf_amc import edit as edit_amc  # noqa: E402
from tests.motion.test_bvh import L_CHEST_OFFSET, L_FRAME_2, L_FRAMES, TINY, edit  # noqa: E402

SIZES = (200_000, 2_000_000, 6_000_000)  # digits; x10 and x30 the first
SITES = "End Site\n{\nOFFSET 0 0 0\n}\n" * 990 + "    End Site\n"


def best(call: Callable[[], object], repeat: int) -> float:
    times = []
    for _ in range(repeat):
        started = time.perf_counter()
        with contextlib.suppress(ParseError):
            call()
        times.append(time.perf_counter() - started)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="best of N (default 3)")
    args = parser.parse_args()
    print(machine())
    places: dict[str, Callable[[str], Callable[[], object]]] = {
        "BVH frame value": lambda t: (
            lambda: read_bvh(edit(TINY, L_FRAME_2, "1 91 2 0 0 0 0 0 " + t))
        ),
        # a hierarchy line is refused past 65,536 characters, so the OFFSET stops at 60,000
        "BVH OFFSET": lambda t: lambda: read_bvh(edit(TINY, L_CHEST_OFFSET, f"OFFSET 0 {t} 0")),
        "AMC value": lambda t: (
            lambda: read_asf_amc(TINY_ASF, edit_amc(TINY_AMC, M_HIP_1, f"hip 5 {t} 7"))
        ),
    }
    for place, make in places.items():
        sizes = list(SIZES) if place != "BVH OFFSET" else [6_000, 20_000, 60_000]
        seconds = [best(make("1" * n + "x"), args.repeat) for n in sizes]
        row = ", ".join(
            f"{n:,} digits {s * 1000:.1f} ms (x{s / seconds[0]:.1f})"
            for n, s in zip(sizes, seconds, strict=True)
        )
        print(f"{place:16}: {row}")
    huge = " ".join(["1.5"] * 2_500_000)
    guards: dict[str, Callable[[], object]] = {
        "10 MB frame line": lambda: read_bvh(edit(TINY, L_FRAME_2, huge)),
        "10 MB line past the frames": lambda: read_bvh(
            edit(edit(TINY, L_FRAME_2, huge), L_FRAMES, "Frames: 1")
        ),
        "300,000 lines past the frames": lambda: read_bvh(TINY + "1 91 2 0 0 0 0 0 90\n" * 300_000),
        "990 End Sites of one name": lambda: read_bvh(TINY.replace("    End Site\n", SITES, 1)),
        "a million braces": lambda: read_bvh("HIERARCHY\n" + "{\n" * 1_000_000),
        "AMC line of 5 million values": lambda: read_asf_amc(
            TINY_ASF, edit_amc(TINY_AMC, M_HIP_1, "hip " + "1 " * 5_000_000)
        ),
    }
    for name, call in guards.items():
        print(f"{name:30}: {best(call, args.repeat) * 1000:8.1f} ms")


if __name__ == "__main__":
    main()
