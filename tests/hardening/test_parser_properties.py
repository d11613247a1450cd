"""Property tests: real files from ``../shared/data`` mutated at random, and random text, go
through the parsers and the whole describe step. Each either gives a valid result or raises
the one input error (``InvalidInput``: ``ParseError``, ``LimitExceeded``...) — never another
exception. No hypothesis deadline: one slow example on a loaded machine is no failure (how
long a parse may take is the live fuzz suite's question, tests/hardening/test_upload_fuzz.py,
with the server's own limits).

``tests/motion/test_bvh.py`` and ``test_asf_amc.py`` fuzz the small committed fixtures; these
add every real file (skipped, naming the folder, when its folder of ../shared/data is absent),
byte-level damage, and the describer.
"""

from __future__ import annotations

import os
import re
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from app.errors import InvalidInput
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import ParseLimits
from app.services.describe import MotionDescriber
from app.services.uploads import Upload
from tests.conftest import shared_data_dir
from tests.motion.conftest import assert_consistent

SHARED = shared_data_dir()
LIMITS = ParseLimits(max_frames=20_000, max_joints=512, max_depth=128, max_values=20_000_000)
FRAMES_KEPT = 12  # real files are cut to their first frames: fast, and mutations hit headers

BVH_FILES = sorted(SHARED.glob("bandai-ds1/data/*.bvh"))[::6] + sorted(
    SHARED.glob("cmu/bvh-*/**/*.bvh")
)
AMC_FILES = sorted(SHARED.glob("cmu/asf-amc/*/*.amc"))

needs_bvh = pytest.mark.skipif(
    not BVH_FILES,
    reason=f"real BVH files not found in {SHARED}/bandai-ds1/data or cmu/bvh-* "
    "(set MOCAP_SHARED_DATA)",
)
needs_amc = pytest.mark.skipif(
    not AMC_FILES,
    reason=f"real AMC files not found in {SHARED}/cmu/asf-amc (set MOCAP_SHARED_DATA)",
)

SPECIAL_TOKENS = [
    "nan",
    "-inf",
    "inf",
    "1e309",
    "-1e309",
    "0",
    "-0",
    "1e-320",
    "99999999999999999999999999",
    "-3",
    "0x10",
    "1_000",
    "٣",  # an Arabic-Indic digit: str.isdigit() says yes, float() too
    "",
    "{",
    "}",
    "End Site",
    "ROOT",
    "JOINT",
    "MOTION",
    "Frames:",
    "begin",
    "end",
    ":root",
    ":bonedata",
    ":hierarchy",
    "\x00",
    "\r",
    "\u2028",
    "\ufeff",
]

DESCRIBER = MotionDescriber(max_values=LIMITS.max_values)
HYPOTHESIS = settings(
    max_examples=int(os.environ.get("MOCAP_FUZZ_EXAMPLES", "120")),
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


@cache
def cut_bvh(path: Path) -> bytes:
    """A real BVH cut to its first frames, ``Frames:`` edited to match."""
    text = path.read_bytes().decode("utf-8").replace("\r\n", "\n")
    header, rest = text.split("MOTION\n", 1)
    lines = rest.split("\n")
    frames = [line for line in lines[2:] if line.strip()][:FRAMES_KEPT]
    return (
        f"{header}MOTION\nFrames: {len(frames)}\n{lines[1]}\n" + "\n".join(frames) + "\n"
    ).encode()


@cache
def cut_amc(path: Path) -> tuple[bytes, bytes]:
    """A real AMC cut to its first frames, with its subject's ASF."""
    asf = next(path.parent.glob("*.asf")).read_bytes()
    out: list[str] = []
    frames = 0
    for line in path.read_bytes().decode("utf-8").replace("\r\n", "\n").split("\n"):
        if re.fullmatch(r"\d+", line.strip()):
            frames += 1
            if frames > FRAMES_KEPT:
                break
        out.append(line)
    return asf, ("\n".join(out) + "\n").encode()


@st.composite
def damaged(draw: st.DrawFn, data: bytes) -> bytes:
    """``data`` with 1-4 edits: bytes flipped, inserted, deleted or repeated, a number swapped
    for a hostile token, lines swapped or the file truncated."""
    for _ in range(draw(st.integers(1, 4))):
        size = len(data)
        at = draw(st.integers(0, max(size - 1, 0)))
        kind = draw(
            st.sampled_from(["flip", "insert", "delete", "repeat", "token", "swap", "truncate"])
        )
        if kind == "flip" and size:
            data = data[:at] + bytes([draw(st.integers(0, 255))]) + data[at + 1 :]
        elif kind == "insert":
            data = data[:at] + draw(st.binary(min_size=1, max_size=12)) + data[at:]
        elif kind == "delete":
            data = data[:at] + data[at + draw(st.integers(1, 200)) :]
        elif kind == "repeat":
            chunk = data[at : at + draw(st.integers(1, 400))]
            data = data[:at] + chunk * draw(st.integers(2, 5)) + data[at:]
        elif kind == "token":
            numbers = list(re.finditer(rb"-?\d+(?:\.\d+)?(?:e-?\d+)?", data))
            if numbers:
                match = numbers[draw(st.integers(0, len(numbers) - 1))]
                token = draw(st.sampled_from(SPECIAL_TOKENS)).encode("utf-8")
                data = data[: match.start()] + token + data[match.end() :]
        elif kind == "swap":
            lines = data.split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            data = b"\n".join(lines)
        elif kind == "truncate":
            data = data[:at]
    return data


def describe_or_reject(upload_parts: dict[str, tuple[str, bytes]]) -> None:
    """The whole describe step: a finite description, or an InvalidInput — nothing else."""
    try:
        upload = Upload.from_files(**upload_parts)  # type: ignore[arg-type]
        description = DESCRIBER.describe(upload, LIMITS)
    except InvalidInput as error:
        assert error.detail and len(error.detail) < 2000
        event(f"describe: {error.code}")
        return
    event("describe: ok")
    assert description.frame_count >= 1 and description.frame_time > 0
    for vector in description.vectors.values():
        assert np.isfinite(vector).all()


def parse_bvh_or_reject(data: bytes | str) -> None:
    try:
        motion = read_bvh(data, limits=LIMITS)
    except InvalidInput as error:
        assert error.detail
        event(f"bvh: {error.code}")
        return
    event("bvh: ok")
    assert_consistent(motion)


def parse_pair_or_reject(asf: bytes | str, amc: bytes | str) -> None:
    try:
        motion = read_asf_amc(asf, amc, limits=LIMITS)
    except InvalidInput as error:
        assert error.detail
        event(f"asf/amc: {error.code}")
        return
    event("asf/amc: ok")
    assert_consistent(motion)


@st.composite
def damaged_bvh(draw: st.DrawFn) -> bytes:
    return draw(damaged(cut_bvh(draw(st.sampled_from(BVH_FILES)))))


@st.composite
def damaged_pair(draw: st.DrawFn) -> tuple[bytes, bytes]:
    asf, amc = cut_amc(draw(st.sampled_from(AMC_FILES)))
    if draw(st.booleans()):
        return draw(damaged(asf)), amc
    return asf, draw(damaged(amc))


@needs_bvh
@needs_amc
def test_every_cut_real_file_describes() -> None:
    """The unmutated starting points are valid: damage, not the cutting, makes files fail."""
    for path in BVH_FILES:
        DESCRIBER.describe(Upload.from_files(file=(path.name, cut_bvh(path))), LIMITS)
    for path in AMC_FILES[::4]:
        asf, amc = cut_amc(path)
        DESCRIBER.describe(
            Upload.from_files(skeleton=("s.asf", asf), motion=(path.name, amc)), LIMITS
        )


@needs_bvh
@HYPOTHESIS
@given(damaged_bvh())
def test_damaged_real_bvh_parses_or_raises_the_input_error(data: bytes) -> None:
    parse_bvh_or_reject(data)


@needs_amc
@HYPOTHESIS
@given(damaged_pair())
def test_damaged_real_asf_amc_parses_or_raises_the_input_error(pair: tuple[bytes, bytes]) -> None:
    parse_pair_or_reject(*pair)


@needs_bvh
@needs_amc
@HYPOTHESIS
@given(
    st.one_of(damaged_bvh().map(lambda d: ("bvh", d)), damaged_pair().map(lambda p: ("pair", p)))
)
def test_damaged_real_files_describe_or_raise_the_input_error(
    item: tuple[str, bytes | tuple[bytes, bytes]],
) -> None:
    kind, data = item
    if kind == "bvh":
        assert isinstance(data, bytes)
        describe_or_reject({"file": ("clip.bvh", data)})
    else:
        assert isinstance(data, tuple)
        describe_or_reject({"skeleton": ("s.asf", data[0]), "motion": ("m.amc", data[1])})


# -- random text, with and without the formats' words ---------------------------------------

BVH_WORDS = st.sampled_from(
    [
        "HIERARCHY",
        "ROOT",
        "JOINT",
        "End",
        "Site",
        "{",
        "}",
        "OFFSET",
        "CHANNELS",
        "3",
        "6",
        "Xposition",
        "Yrotation",
        "Zrotation",
        "MOTION",
        "Frames:",
        "Frame",
        "Time:",
        "0.1",
        "1",
        "-2.5",
        "nan",
        "\n",
        "\n",
        "\n",
    ]
)
ASF_WORDS = st.sampled_from(
    [
        ":units",
        ":root",
        ":bonedata",
        ":hierarchy",
        "begin",
        "end",
        "name",
        "root",
        "b1",
        "b2",
        "direction",
        "length",
        "axis",
        "dof",
        "rx",
        "ry",
        "tz",
        "XYZ",
        "order",
        "TX",
        "RX",
        "angle",
        "deg",
        "0",
        "1",
        "1",
        "\n",
        "\n",
        "\n",
    ]
)


@HYPOTHESIS
@given(st.one_of(st.binary(max_size=2000), st.text(max_size=2000)))
def test_random_bytes_and_text_as_bvh(data: bytes | str) -> None:
    parse_bvh_or_reject(data)


@HYPOTHESIS
@given(st.lists(BVH_WORDS, max_size=300).map(" ".join))
def test_random_bvh_words(text: str) -> None:
    parse_bvh_or_reject(text)
    describe_or_reject({"file": ("w.bvh", text.encode())})


@HYPOTHESIS
@given(
    st.lists(ASF_WORDS, max_size=300).map(" ".join),
    st.one_of(
        st.text(max_size=300),
        st.lists(st.sampled_from(["1", "b1 0", "root 0 0", "\n"])).map(" ".join),
    ),
)
def test_random_asf_amc_words(asf: str, amc: str) -> None:
    parse_pair_or_reject(asf, amc)
