"""The describer (app/services/describe.py): one verdict whatever a route computes, a time
limit that reaches into the read, and every clip and window vector of the real data finite.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pytest

from app.config import Settings
from app.discovery import ClipSource, discover
from app.errors import (
    DescribeTimeout,
    InvalidInput,
    LimitExceeded,
    MocapError,
    NoAnimation,
    ParseError,
    UnreadableFile,
)
from app.motion.model import ParseLimits
from app.services.describe import MotionDescriber
from app.services.parser_pool import InlineParser
from app.services.uploads import Upload
from tests.conftest import FIXTURES_DIR, shared_data_dir
from tests.hostile.make_corpus import _edit_frame_value, base_bvh

LIMITS = Settings().parse_limits


def _verdicts(describer: MotionDescriber, data: bytes) -> list[str]:
    """What each way of describing an upload says: 'ok' or the error code. The upload and
    the import describe everything and the windows; the search only the asked descriptor;
    the moments search a span and its own windows."""
    upload = Upload.from_files(file=("take.bvh", data))
    calls: list[Callable[[], object]] = [
        lambda: describer.describe(upload, LIMITS),
        lambda: describer.describe(upload, LIMITS, only=["motion"]),
        lambda: describer.describe(upload, LIMITS, only=["posture"]),
        lambda: describer.describe_span(
            upload, LIMITS, "motion", None, None, part_length=lambda seconds: seconds / 2
        ),
    ]
    out = []
    for call in calls:
        try:
            call()
            out.append("ok")
        except MocapError as error:
            out.append(error.code)
    return out


@pytest.mark.parametrize(
    ("value", "frame", "column", "verdict"),
    [
        ("1e308", 2, 0, "parse_error"),  # the root thrown to a sentinel: no pose
        ("-1e30", 3, 1, "parse_error"),
        ("1e30", 2, 8, "ok"),  # a rotation of 1e30 degrees is some rotation
        ("nan", 2, 4, "ok"),  # a missing value, filled in
        ("1e-300", 2, 4, "ok"),
    ],
)
def test_one_reader_one_verdict(value: str, frame: int, column: int, verdict: str) -> None:
    """Fuzzed files once stored by the search and refused by the upload (a whole-clip
    'motion' vector finite, a 'posture' or window vector not): now every route gives the
    same answer."""
    data = _edit_frame_value(base_bvh(5), value, frame=frame, column=column).encode()
    assert _verdicts(MotionDescriber(), data) == [verdict] * 4


@pytest.mark.parametrize(
    "edit",
    [
        lambda text: text.replace("CHANNELS 3", "CHANNELS 7", 1),
        lambda text: text.replace(
            "CHANNELS 3 Zrotation Yrotation Xrotation",
            "CHANNELS 7 Zrotation Yrotation Xrotation Xposition Yposition Zposition Xrotation",
            1,
        ),
        lambda text: text.replace("Frame Time: .0083333", "Frame Time: 1e-300"),
    ],
)
def test_header_faults_get_one_verdict(edit: Callable[[str], str]) -> None:
    data = edit(base_bvh(5)).encode()
    verdicts = _verdicts(MotionDescriber(), data)
    assert len(set(verdicts)) == 1 and verdicts[0] != "ok", verdicts


def test_the_describe_time_limit_reaches_into_the_read(monkeypatch: pytest.MonkeyPatch) -> None:
    """A clock that moves one second per look: the read looks at it every few thousand lines
    of a long frame block, so the 20-second limit stops it inside the parse (before, it was
    only checked once the read was over)."""
    looks = [0.0]

    def clock() -> float:
        looks[0] += 1.0
        return looks[0]

    monkeypatch.setattr(time, "monotonic", clock)
    text = base_bvh(5) + "0\n" * 400_000  # short lines past the declared frames
    upload = Upload.from_files(file=("long.bvh", text.encode()))
    with pytest.raises(DescribeTimeout, match="while reading the file") as raised:
        MotionDescriber(time_limit=20.0).describe(upload, LIMITS)
    assert "MOCAP_DESCRIBE_TIMEOUT_SECONDS" in raised.value.detail
    assert looks[0] < 40  # a whole walk takes 100 looks


def test_a_read_within_the_limit_is_not_stopped() -> None:
    upload = Upload.from_files(file=("walk.bvh", base_bvh(5).encode()))
    description = MotionDescriber(time_limit=30.0).describe(upload, LIMITS)
    assert description.frame_count == 5


# -- the sweep: every clip of ../shared/data ----------------------------------------------

SWEPT = ("bandai-ds1", "cmu", "wild-bvh", "fbx-gltf", "wild-more")
# What a clip may be refused for: its file (damaged, over a limit, a rig) or its skeleton.
# Never InvalidInput itself, the class of the 'degenerate motion' refusals.
FILE_REFUSALS = (ParseError, LimitExceeded, UnreadableFile)


def _upload(source: ClipSource, animation: str | None = None) -> Upload:
    if source.skeleton is not None:
        return Upload.from_files(
            skeleton=(source.skeleton.name, source.skeleton.read_bytes()),
            motion=(source.motion.name, source.motion.read_bytes()),
        )
    return Upload.from_files(
        file=(source.motion.name, source.motion.read_bytes()), animation=animation
    )


def _animations(source: ClipSource) -> list[str | None]:
    """Every animation of an FBX/glTF file by name (``[None]``: the file's only clip, or a
    file the reader refuses before listing anything)."""
    if source.kind not in ("fbx", "gltf"):
        return [None]
    from app.motion.formats.fbx import list_fbx_animations
    from app.motion.formats.gltf import list_gltf_animations

    lister = list_fbx_animations if source.kind == "fbx" else list_gltf_animations
    try:
        names: list[str | None] = [a.name for a in lister(source.motion.read_bytes())]
    except MocapError:
        return [None]
    return names or [None]


def _check_finite(description: object, where: str) -> None:
    vectors = description.vectors  # type: ignore[attr-defined]
    windows = description.windows  # type: ignore[attr-defined]
    for name, vector in vectors.items():
        assert np.all(np.isfinite(vector)), f"{where}: clip vector {name!r}"
    assert windows is not None, where
    for name, array in windows.vectors.items():
        assert len(array) and np.all(np.isfinite(array)), f"{where}: window vectors {name!r}"


@pytest.mark.slow
@pytest.mark.parametrize("folder", SWEPT)
def test_every_clip_and_window_vector_of_the_real_data_is_finite(folder: str) -> None:
    """Every clip of ``../shared/data/<folder>`` (every animation of a multi-animation file):
    described with every clip and window vector finite, or refused for what its file or
    skeleton is (a parse error, a rig, a limit, an unmappable skeleton) -- never for
    'degenerate motion'. FBX and glTF are read in this process by the InlineParser (about a
    minute of CPU for the five folders)."""
    root = shared_data_dir() / folder
    if not root.is_dir():
        pytest.skip(f"{folder}/ not found in {root.parent} (set MOCAP_SHARED_DATA)")
    describer = MotionDescriber(parsers=InlineParser(time_limit=60.0, memory_mb=2048))
    described = refused = 0
    for source in discover([root], scenes=True).sources:
        for animation in _animations(source):
            where = f"{source.relative_path}" + (f" [{animation}]" if animation else "")
            try:
                description = describer.describe(_upload(source, animation), LIMITS)
            except FILE_REFUSALS as error:
                assert "not finite" not in error.detail, f"{where}: {error.detail}"
                refused += 1
                continue
            except InvalidInput as error:  # the class of the degenerate-vector refusals
                pytest.fail(f"{where}: {error.code}: {error.detail}")
            _check_finite(description, where)
            described += 1
    assert described > 0
    print(f"{folder}: {described} clips described, {refused} refused")


def test_the_sweep_sees_rig_only_files_as_rigs() -> None:
    """The fixture rig (a BVH hierarchy with Frames: 0) is refused as no_animation by the
    describer, a file refusal the sweep accepts, never a degenerate vector."""
    text = base_bvh(5).replace("Frames: 5", "Frames: 0")
    with pytest.raises(NoAnimation):
        MotionDescriber().describe(Upload.from_files(file=("rig.bvh", text.encode())), LIMITS)
    assert issubclass(NoAnimation, FILE_REFUSALS)


def test_fixture_fbx_is_described_through_the_inline_parser() -> None:
    """The sweep's way of reading FBX, on the committed fixture (runs without ../shared)."""
    data = (FIXTURES_DIR / "ufbx_maya_human_ik_7400_binary.fbx").read_bytes()
    describer = MotionDescriber(parsers=InlineParser())
    description = describer.describe(Upload.from_files(file=("hik.fbx", data)), ParseLimits())
    _check_finite(description, "fixture fbx")
