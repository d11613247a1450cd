"""Rest poses that are not a rest: real rigs rewritten as video-derived and pose-estimator
exporters write them (issue 20, item 7; docs/skeletons.md, "2026-11-27, rest poses that are
not a rest").

Each rig keeps its world motion and gets another way of writing it:

* (a) bones along odd axes: every joint's local axes turned (a signed permutation of the
  axes, or a random turn), the channels conjugated, so the OFFSETs lie anywhere;
* (b) all-zero rotations meaning a pose that is not standing: every joint's axes turned 90
  degrees alike (the rest pose lies), or the middle frame written as the rest pose;
* (c) one-frame and two-frame clips, their own first frame as rest or bones in random axes;
* (d) a take that never stands: the whole motion turned 90 degrees about a horizontal axis
  (lying), with its first frame, or a lying figure, as rest;
* (e) a left-handed export: one world axis negated (the names then lie on the mirror
  image's sides: the mapping must be the same joints, taken as a mirrored capture).

Four measures per copy: the mapping (the same source joints by name, mirrored exactly when
the copy is), the body's axes (the pelvis frame's up within 30 degrees and forward within 45
degrees of the original's, the median over the frames, read back through the probe's world
change) and what a user sees (the copy's stored ``motion``, ``posture`` and ``kinetic``
vectors each find the original first among the dev files; and ``motion``, the default
search, alone). The CMU and Bandai fixtures must
map alike, axes right, under every probe; the development rigs are ratchets, with the counts
of each measure recorded. No probed copy may fail otherwise than with a
:class:`~app.errors.MocapError` (a 4xx).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import MocapError
from app.motion import transforms
from app.motion.formats import read_bvh
from app.motion.ground import sample_frames
from app.motion.model import Motion
from app.motion.pipeline import analyse, describable_body
from tests.conftest import shared_data_dir
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.holds import frames_at
from tests.motion.read_once import read_only
from tests.motion.test_mapping_probes import frame_as_rest, rebased
from tests.motion.test_nameless_real import FILES

_TURN = transforms.rotation_about([1.0, 0.0, 0.0], 90.0)  # about a horizontal axis
_LEFT_HANDED = np.diag([1.0, 1.0, -1.0])  # a right-handed file written left-handed


def signed_axes(motion: Motion, seed: int = 1) -> Motion:
    """Every joint's local axes a signed permutation of its own (rotations only): each
    OFFSET then lies along another axis, as in a writer whose bones point along x, y or z."""
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(motion.skeleton.joint_count):
        while True:
            turn = np.eye(3)[rng.permutation(3)] * rng.choice([-1.0, 1.0], 3)
            if np.linalg.det(turn) > 0:
                break
        frames.append(turn)
    return rebased(motion, np.stack(frames))


def random_axes(motion: Motion, seed: int = 3) -> Motion:
    """Every joint's local axes turned at random (a rest pose that is no figure at all)."""
    return rebased(motion, Rotation.random(motion.skeleton.joint_count, seed).as_matrix())


def all_turned(motion: Motion, turn: np.ndarray = _TURN) -> Motion:
    """Every joint's axes turned by one ``(3, 3)`` ``turn``: the rest pose is the standing
    one turned (lying), the motion unchanged."""
    return rebased(motion, np.broadcast_to(turn, (motion.skeleton.joint_count, 3, 3)).copy())


def middle(motion: Motion, count: int) -> Motion:
    """``count`` frames from the middle of the clip."""
    start = max(0, motion.frame_count // 2 - count // 2)
    return frames_at(motion, np.arange(start, min(motion.frame_count, start + count)))


# Probe -> (the rewritten copy, the frames of the original it shows, the world change
# ``(3, 3)`` from the original's coordinates to the copy's).
Probe = tuple[Callable[[Motion], Motion], Callable[[Motion], Motion], np.ndarray]
_SAME: Callable[[Motion], Motion] = lambda m: m  # noqa: E731
_ONE: Callable[[Motion], Motion] = lambda m: middle(m, 1)  # noqa: E731
_TWO: Callable[[Motion], Motion] = lambda m: middle(m, 2)  # noqa: E731
PROBES: dict[str, Probe] = {
    "a: bones along signed axes": (signed_axes, _SAME, np.eye(3)),
    "a: bones in random axes": (random_axes, _SAME, np.eye(3)),
    "b: rest pose lying": (all_turned, _SAME, np.eye(3)),
    "b: middle frame as rest": (
        lambda m: frame_as_rest(m, m.frame_count // 2),
        _SAME,
        np.eye(3),
    ),
    "c: one frame": (_ONE, _ONE, np.eye(3)),
    "c: one frame, it as rest": (lambda m: frame_as_rest(_ONE(m)), _ONE, np.eye(3)),
    "c: one frame, random axes": (lambda m: random_axes(_ONE(m), 5), _ONE, np.eye(3)),
    "c: two frames, first as rest": (lambda m: frame_as_rest(_TWO(m)), _TWO, np.eye(3)),
    "c: two frames, random axes": (lambda m: random_axes(_TWO(m), 5), _TWO, np.eye(3)),
    "d: take lying, first frame as rest": (
        lambda m: frame_as_rest(transforms.rotate(m, _TURN)),
        _SAME,
        _TURN,
    ),
    "d: take lying, rest pose lying": (
        lambda m: all_turned(transforms.rotate(m, _TURN)),
        _SAME,
        _TURN,
    ),
    "e: left-handed": (
        lambda m: transforms.change_basis(m, _LEFT_HANDED),
        _SAME,
        _LEFT_HANDED,
    ),
    "e: left-handed, first frame as rest": (
        lambda m: frame_as_rest(transforms.change_basis(m, _LEFT_HANDED)),
        _SAME,
        _LEFT_HANDED,
    ),
}
_UP_WITHIN = np.cos(np.radians(30.0))
_FORWARD_WITHIN = np.cos(np.radians(45.0))


# (the mapped source joints by name, mirrored, ``(F, 3, 3)`` the body frames in the
# original's coordinates, the lead-in frames dropped before them, the stored descriptor
# vectors by name)
Reading = tuple[tuple[str, ...], bool, np.ndarray, int, dict[str, np.ndarray]]


def _reading(motion: Motion, world: np.ndarray) -> Reading:
    """How the service reads ``motion``: its mapping and its body frames with ``world`` (the
    probe's world change) undone, and the mirror the body describes undone too."""
    body = describable_body(motion)
    mapping = body.mapping
    assert mapping is not None
    undo = world.T
    if mapping.mirrored:
        flip = np.ones(3)
        flip[mapping.mirror_axis] = -1.0
        undo = undo @ np.diag(flip)
    names = tuple(motion.skeleton.names[j] for j in mapping.joints)
    vectors = analyse(motion, body=body).descriptors
    return names, mapping.mirrored, undo @ body.pelvis_frames, body.lead_in_frames, vectors


def axes_right(got: Reading, expected: Reading) -> bool:
    """The body's up within 30 degrees and forward within 45 of ``expected``'s, as the median
    over the frames both keep (a probe can change how many lead-in frames are dropped).

    Frame by frame, not the mean frame's axes: a take that turns round has a short mean
    forward, so a steady tilt of 12 degrees read 46 through the mean (docs/skeletons.md,
    "2026-11-27, a rest pose one frame shows"), while what the descriptors see is each
    frame's axes."""
    frames, lead_in = got[2], got[3]
    known, known_lead_in = expected[2], expected[3]
    shift = lead_in - known_lead_in  # frame f of ``got`` is frame f + shift of ``known``
    first = max(0, -shift)
    count = min(len(frames) - first, len(known) - first - shift)
    if count <= 0:
        return False
    frames = frames[first : first + count]
    known = known[first + shift : first + shift + count]
    cosines = np.einsum("fac,fac->cf", frames, known)  # (3, F): per axis and frame
    up, forward = np.median(cosines[1]), np.median(cosines[2])
    return bool(up >= _UP_WITHIN and forward >= _FORWARD_WITHIN)


def outcome(motion: Motion, probe: str, original: Reading | None = None) -> tuple[str, bool]:
    """("same" | "refused: ..." | "differ ...", body axes right) of ``motion`` under
    ``probe`` (``original``: ``motion``'s own reading, when known); anything but a
    MocapError is raised (it would be a 500)."""
    verdict, axes, _ = probed(motion, probe, original)
    return verdict, axes


def probed(
    motion: Motion,
    probe: str,
    original: Reading | None = None,
    shown_reading: tuple[Reading | None] | None = None,
) -> tuple[str, bool, Reading | None]:
    """:func:`outcome`, and the probed copy's reading when it maps alike (``shown_reading``:
    the reading of the frames the probe shows, when known, in a 1-tuple; None in it: those
    frames are refused)."""
    rewrite, shown, world = PROBES[probe]
    expected: Reading | None = original or _reading(motion, np.eye(3))
    assert expected is not None
    names, mirrored = expected[0], expected[1]
    if shown is not _SAME and shown_reading is not None:
        expected = shown_reading[0]
    elif shown is not _SAME:
        try:
            expected = _reading(shown(motion), np.eye(3))
        except MocapError:
            expected = None  # the frames themselves show no body: only the mapping is compared
    try:
        got = _reading(rewrite(motion), world)
    except MocapError as error:
        return f"refused: {error}", False, None
    expected_mirror = bool(np.linalg.det(world) < 0) != mirrored
    if got[0] != names or got[1] != expected_mirror:
        pairs = [(a, b) for a, b in zip(names, got[0], strict=True) if a != b]
        return f"differ {pairs}, mirrored {got[1]}", False, None
    return "same", expected is not None and axes_right(got, expected), got


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_the_fixtures_map_alike_under_every_rest_that_is_not_a_rest(fixture: str) -> None:
    motion = sample_frames(read_bvh(fixture_bytes(fixture)), 60)
    found = {probe: outcome(motion, probe) for probe in PROBES}
    assert all(v == ("same", True) for v in found.values()), found  # joints and body axes


def family(path: Path) -> str:
    """The dev-set folder a file belongs to (``wild-bvh/mixamo``)."""
    parts = path.relative_to(shared_data_dir()).parts
    return f"{parts[0]}/{parts[1]}"


@functools.cache
def _dev_motions() -> tuple[tuple[Path, Motion, Reading], ...]:
    """The human dev BVH files, 60 frames spread over each (the mapper reads a dozen), with
    their own reading: parsed and read once for every probe."""
    found = []
    for path in FILES:
        motion = read_only(sample_frames(read_bvh(path.read_bytes()), 60))
        found.append((path, motion, _reading(motion, np.eye(3))))
    return tuple(found)


@functools.cache
def _shown_readings(shown: Callable[[Motion], Motion]) -> dict[Path, Reading | None]:
    """Every dev file's own reading of the frames ``shown`` keeps (the whole file, or the one
    or two frames a probe cuts), unprobed: read once for all the probes that show the same
    frames; None where the cut is refused."""
    found: dict[Path, Reading | None] = {}
    for path, motion, read in _dev_motions():
        if shown is _SAME:
            found[path] = read
            continue
        try:
            found[path] = _reading(shown(motion), np.eye(3))
        except MocapError:
            found[path] = None
    return found


@functools.cache
def _shown_vectors(probe: str) -> dict[Path, dict[str, np.ndarray]]:
    """The stored descriptors of every dev file as ``probe`` shows it, unprobed; files whose
    cut is refused are left out."""
    _, shown, _ = PROBES[probe]
    return {path: read[4] for path, read in _shown_readings(shown).items() if read is not None}


def finding_the_original(path: Path, vectors: dict[str, np.ndarray], probe: str) -> set[str]:
    """The probed copy's stored descriptors (of ``motion``, ``posture``, ``kinetic``) that
    find the unprobed file first among the dev files (ties, such as a one-frame clip's
    empty kinetic vector, count for the original)."""
    originals = _shown_vectors(probe)
    if path not in originals:
        return set()
    finding = set()
    for name, vector in vectors.items():
        distance = {q: float(np.linalg.norm(vector - v[name])) for q, v in originals.items()}
        if distance[path] <= min(distance.values()):
            finding.add(name)
    return finding


def nearest_is_the_original(path: Path, vectors: dict[str, np.ndarray], probe: str) -> bool:
    """What a user sees: each of the probed copy's stored descriptors finds the unprobed file
    first among the dev files."""
    return finding_the_original(path, vectors, probe) == set(vectors)


def dev_outcomes(probe: str) -> dict[Path, tuple[str, bool, bool, bool]]:
    """Per dev file: (mapping verdict, body axes right, the original found first by all
    three stored descriptors, by ``motion``, the default search, alone)."""
    found = {}
    shown = _shown_readings(PROBES[probe][1])
    for path, motion, read in _dev_motions():
        verdict, axes, got = probed(motion, probe, read, (shown[path],))
        finding = set() if got is None else finding_the_original(path, got[4], probe)
        every = got is not None and finding == set(got[4])
        found[path] = (verdict, axes, every, "motion" in finding)
    return found


# Human dev BVH files (66) whose probed copy maps like the file, of those whose body axes are also
# right, and of those found first by their stored descriptors, at least (ratchets: raise them as
# the mapper and the body frame improve). The body's axes come from the frames when the rest pose
# is no pose of the body (app/motion/body.py, pelvis_basis): before, bones along odd axes mapped
# right but faced anywhere (signed axes 8, random axes 19, one or two frames in random axes 23). A
# single pose standing on one leg is read since 2026-11-27 (app/motion/mapping/take.py,
# map_on_one_leg): the mapping counts rose by 1-4 per probe, none fell. Since 2026-11-27 the axes
# are compared frame by frame (axes_right) and a third count says what a user sees: the copies
# found first by their own stored descriptors. The per-frame axes moved three files on main:
# romp_dance2 and romp_dance5 (smpl-video) under random axes, 30.25 degrees off in every frame,
# passed through the mean axes of their turning dance (their posture vectors 1.1-1.3 of the dev
# files' median distance from the original's), and eggfryonrice_walking and _dancing, 12-29
# degrees off, failed through their short mean forward (random axes 51 -> 50, middle frame as rest
# and take lying 54 -> 56, left-handed 52 -> 54). Up from the world's up seen from the pelvis when
# most frames stand (app/motion/body_axes.py, frames_basis) raised the axes of the copies read
# from their frames (signed axes 56 -> 61, random axes 50 -> 55, one frame 54 -> 58, two frames 54
# -> 57) and the copies found first (42 -> 46, 31 -> 35, two frames 35 -> 37) but one frame in
# random axes 35 -> 34: a single pose's pelvis tilt is no smaller than its spine's bend as often
# as not (five files found first now, six no longer).
# A fourth count since 2026-11-27: the copies (mapped alike) whose ``motion`` vector, the default
# search's, finds the original first. Every copy that maps alike with its axes right and is not
# found first by all three is missed by ``posture`` (104 of 104 such pairs, seven probes, the
# files not held out; one by ``motion`` too), and described with the original's body axes all
# three of its vectors are the original's to rounding (75 pairs of five probes; 3 more keep a
# lead-in frame the original drops; tests/motion/test_body_axes.py): what tells it apart is the
# body's pitch, 5-29 degrees, which a rest pose that is no writer's rest cannot tell
# (docs/skeletons.md, "2026-11-27, what tells an odd-rest copy from its original").
# Raised 2026-11-28 to the counts measured with the floor's vertical and ``motion`` 5's heading
# square to the hips (docs/skeletons.md, "a fall whose rest pose lies, and a lying body's
# heading"): found first by motion +1 under signed axes, random axes and the middle frame as
# rest; one frame / two frames in random axes had one to spare in three counts already.
RECORDED: dict[str, tuple[int, int, int, int]] = {
    "a: bones along signed axes": (62, 61, 47, 62),
    "a: bones in random axes": (60, 55, 36, 60),
    "b: rest pose lying": (66, 66, 66, 66),
    "b: middle frame as rest": (61, 56, 39, 59),
    "c: one frame": (66, 66, 66, 66),
    "c: one frame, it as rest": (59, 54, 42, 56),
    "c: one frame, random axes": (60, 59, 35, 58),
    "c: two frames, first as rest": (60, 55, 40, 58),
    "c: two frames, random axes": (60, 58, 38, 59),
    "d: take lying, first frame as rest": (62, 56, 41, 60),
    "d: take lying, rest pose lying": (66, 66, 66, 66),
    "e: left-handed": (64, 64, 64, 64),
    "e: left-handed, first frame as rest": (60, 54, 39, 58),
}


@pytest.mark.skipif(not FILES, reason="no wild-bvh or wild-more in ../shared/data")
@pytest.mark.parametrize("probe", list(PROBES))
def test_human_dev_rigs_under_a_rest_that_is_not_a_rest(probe: str) -> None:
    found = dev_outcomes(probe)
    maps = sum(v == "same" for v, _, _, _ in found.values())
    upright = sum(v == "same" and axes for v, axes, _, _ in found.values())
    first = sum(v == "same" and near for v, _, near, _ in found.values())
    by_motion = sum(v == "same" and near for v, _, _, near in found.values())
    print(
        f"{probe}: {maps} of {len(found)} map alike, {upright} with the body's axes right, "
        f"{first} found first by their own descriptors, {by_motion} by motion"
    )
    failed = {f"{family(p)}/{p.name}": v for p, (v, _, _, _) in found.items() if v != "same"}
    assert maps >= RECORDED[probe][0], failed
    assert upright >= RECORDED[probe][1], failed
    assert first >= RECORDED[probe][2], failed
    assert by_motion >= RECORDED[probe][3], failed
