"""A take that never stands: real rigs rewritten so that neither the rest pose nor any frame
is a standing figure, as video-derived and pose-estimator BVH often are (issue 20, item 7;
docs/skeletons.md, "A body from a take that never stands").

Each real rig (the CMU and Bandai excerpts in tests/fixtures and, where ../shared is present,
every human BVH of the development sets) is posed otherwise in every frame — seated (thighs
forward, shins down), crouched (thighs up and forward, shins down and back, the trunk leaning
forward), lying on its back with the knees drawn up — with the first frame written as the
rest pose (each joint's axes its world axes there), and cut to the frames of its own that are
no standing figure, when it has some. Forward kinematics keeps every bone's length, so the
same source joints must be found, by name. The CMU and Bandai fixtures pass every probe; the
development rigs are ratchets that say which fail.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import MocapError
from app.motion.formats import read_bvh
from app.motion.ground import map_clip, sample_frames
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.holds import frames_at
from tests.motion.skeleton_trees import Humanoid, synthetic_humanoid
from tests.motion.synthetic import bones_scaled, walking
from tests.motion.test_mapping_probes import _named_mapping, frame_as_rest
from tests.motion.test_nameless_real import FILES

# Turns about the body's lateral axis (degrees; positive leans the trunk forward, negative
# lifts a thigh forward), applied in order at each canonical joint, in every frame, on top of
# the clip's own (so a knee turn leaves room for the clip's knee bend below 180 degrees).
POSTURES: dict[str, tuple[tuple[str, float], ...]] = {
    "seated": (("l_hip", -95.0), ("r_hip", -95.0), ("l_knee", 85.0), ("r_knee", 85.0)),
    "crouched": (
        ("spine", 30.0),
        ("l_hip", -110.0),
        ("r_hip", -110.0),
        ("l_knee", 100.0),
        ("r_knee", 100.0),
    ),
    "lying, knees up": (
        ("pelvis", -90.0),
        ("l_hip", -110.0),
        ("r_hip", -110.0),
        ("l_knee", 100.0),
        ("r_knee", 100.0),
    ),
}


def _at(names: tuple[str, ...], motion: Motion, canonical: str) -> int:
    return motion.skeleton.names.index(names[CANONICAL_INDEX[canonical]])


def body_axes(motion: Motion, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(F, 3)`` the subject's left and ``(F, 3)`` up (pelvis -> neck) in every frame."""
    _, positions = forward_kinematics(motion)
    up = positions[:, _at(names, motion, "neck")] - positions[:, _at(names, motion, "pelvis")]
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    for part in ("hip", "knee", "ankle"):
        left = (
            positions[:, _at(names, motion, f"l_{part}")]
            - positions[:, _at(names, motion, f"r_{part}")]
        )
        left -= np.sum(left * up, axis=1, keepdims=True) * up
        size = np.linalg.norm(left, axis=1, keepdims=True)
        if float(size.min()) > 1e-6 * float(np.ptp(positions)):
            return left / size, up
    raise AssertionError("the legs coincide")


def posed(
    motion: Motion, names: tuple[str, ...], posture: str | tuple[tuple[str, float], ...]
) -> Motion:
    """``motion`` with every frame turned into ``posture`` (see :data:`POSTURES`, or its
    turns themselves): each turn is about the subject's left at that frame, at the canonical
    joint named, and carries everything below it."""
    left, _ = body_axes(motion, names)
    rotations = motion.local_rotations.copy()
    parents = motion.skeleton.parents
    turns = POSTURES[posture] if isinstance(posture, str) else posture
    for canonical, degrees in turns:
        joint = _at(names, motion, canonical)
        turn = Rotation.from_rotvec(np.radians(degrees) * left).as_matrix()  # (F, 3, 3)
        world, _ = forward_kinematics(
            dataclasses.replace(motion, local_rotations=rotations), joints=[joint]
        )
        above = (
            world[:, int(parents[joint])]
            if parents[joint] >= 0
            else np.broadcast_to(np.eye(3), turn.shape)
        )
        # W_joint' = Q W_joint, the parent's frame unchanged: L' = W_parent^T Q W_parent L.
        rotations[:, joint] = np.swapaxes(above, 1, 2) @ turn @ above @ rotations[:, joint]
    return dataclasses.replace(motion, local_rotations=rotations)


def standing_frames(motion: Motion, names: tuple[str, ...]) -> np.ndarray:
    """``(F,)`` bool: the frames that show a standing figure as the mapper reads one (both
    ankles below the pelvis by half their leg, the legs opposite the spine)."""
    _, positions = forward_kinematics(motion)
    _, up = body_axes(motion, names)
    pelvis = positions[:, _at(names, motion, "pelvis")]
    standing = np.ones(motion.frame_count, dtype=bool)
    legs = np.zeros_like(pelvis)
    for side in "lr":
        hip = positions[:, _at(names, motion, f"{side}_hip")]
        knee = positions[:, _at(names, motion, f"{side}_knee")]
        ankle = positions[:, _at(names, motion, f"{side}_ankle")]
        length = np.linalg.norm(knee - hip, axis=1) + np.linalg.norm(ankle - knee, axis=1)
        drop = np.sum((pelvis - ankle) * up, axis=1)
        standing &= drop >= 0.5 * length
        leg = ankle - pelvis
        legs += leg / np.linalg.norm(leg, axis=1, keepdims=True)
    legs /= np.linalg.norm(legs, axis=1, keepdims=True)
    return standing & (np.sum(legs * up, axis=1) <= -0.5)


def rest_probes(motion: Motion, names: tuple[str, ...] | None = None) -> dict[str, Motion]:
    """Name -> the rig written with no standing figure in its rest pose or its frames;
    ``names``: the rig's mapped joint names when already known."""
    if names is None:
        names, _ = _named_mapping(motion)
    takes = {posture: posed(motion, names, posture) for posture in POSTURES}
    probes = {f"{posture} take": frame_as_rest(take) for posture, take in takes.items()}
    seated_start = frames_at(takes["seated"], np.array([0]))
    first = motion.local_rotations.copy()
    first[0] = seated_start.local_rotations[0]
    probes["seated first frame as rest"] = frame_as_rest(
        dataclasses.replace(motion, local_rotations=first)
    )
    lying = ~standing_frames(motion, names)
    if lying.any() and not lying.all():
        probes["its frames that do not stand"] = frame_as_rest(frames_at(motion, lying))
    return probes


PROBES = (
    "seated take",
    "crouched take",
    "lying, knees up take",
    "seated first frame as rest",
    "its frames that do not stand",
)


def _outcome(named: tuple[tuple[str, ...], bool], probed: Motion) -> str | None:
    """None when ``probed`` maps like the rig did, else how not."""
    try:
        got = _named_mapping(probed)
    except MocapError as error:
        return f"refused: {error}"
    pairs = [(a, b) for a, b in zip(named[0], got[0], strict=True) if a != b]
    return None if got == named else f"differ {pairs}, mirrored {got[1]}"


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_the_fixtures_map_alike_in_a_take_that_never_stands(fixture: str) -> None:
    motion = read_bvh(fixture_bytes(fixture))
    named = _named_mapping(motion)
    names = named[0]
    probes = rest_probes(motion, names)
    for name, probed in probes.items():
        # The probe moves joints, never a bone's length.
        _, a = forward_kinematics(motion)
        _, b = forward_kinematics(probed)
        parents = motion.skeleton.parents[1:]
        np.testing.assert_allclose(
            np.linalg.norm(b[:, 1:] - b[:, parents], axis=-1),
            np.linalg.norm(a[:, 1:] - a[:, parents], axis=-1),
            atol=1e-6 * np.ptp(a),
        )
        if not name.startswith("seated first"):  # (a walk's stride may still read as one)
            assert standing_frames(probed, names).mean() < 0.1, name
        assert _outcome(named, probed) is None, name


def _dev_outcomes() -> dict[str, dict[str, str | None]]:
    """Probe -> dev file -> None when the probed copy maps like the file, else how not."""
    found: dict[str, dict[str, str | None]] = {probe: {} for probe in PROBES}
    for path in FILES:
        # The mapper reads a dozen frames: 120 spread over the clip keep the probes quick.
        motion = sample_frames(read_bvh(path.read_bytes()), 120)
        named = _named_mapping(motion)
        for probe, probed in rest_probes(motion, named[0]).items():
            found[probe][path.name] = _outcome(named, probed)
    return found


# Human BVH files of the development sets whose probed copy maps alike, at least (a ratchet).
# On main before the take was read as a body (2026-11-26): 4, 0, 1, 50 and 7 (of 25); before
# a single pose on one leg was read (2026-11-27), 58 and 15 for the last two.
RECORDED = {
    "seated take": 52,
    "crouched take": 41,
    "lying, knees up take": 41,
    "seated first frame as rest": 59,
    "its frames that do not stand": 17,
}


@pytest.mark.skipif(not FILES, reason="no wild-bvh or wild-more in ../shared/data")
def test_human_dev_rigs_in_a_take_that_never_stands() -> None:
    outcomes = _dev_outcomes()
    failed = {}
    for probe, files in outcomes.items():
        same = sum(v is None for v in files.values())
        print(f"{probe}: {same} of {len(files)} map alike")
        if same < RECORDED[probe]:
            failed[probe] = {k: v for k, v in files.items() if v}
    assert not failed, failed


SHAPES = [
    Humanoid(),
    Humanoid(names="anon"),
    Humanoid(names="anon", clavicle=False, spines=1, neck=False, toes=False, hand="none"),
    Humanoid(names="anon", hips_coincide=True, hand="bone"),
    Humanoid(names="anon", arm_angle=45.0, twist_bones=True, face_bones=8),
]


# Synthetic shape x posture cases that map like the standing take, at least (a ratchet);
# the others must be refused, never mapped otherwise.
RECORDED_SYNTHETIC = 14


def test_synthetic_rigs_map_alike_in_a_take_that_never_stands() -> None:
    """Synthetic humanoids of several shapes (without names too) walking, then seated,
    crouched and lying with their first frame written as the rest pose: the same joints as
    the standing take, never mirrored, with a warning that no pose stood; or refused (the
    one case left: hips at the pelvis, lying with the legs swinging, whose feet rest on the
    floor in too few frames)."""
    alike, wrong = 0, {}
    for shape in SHAPES:
        skeleton, truth = synthetic_humanoid(shape)
        motion = walking(skeleton, truth)
        named = _named_mapping(motion)
        assert named[0][CANONICAL_INDEX["l_knee"]] == truth["l_knee"]
        for posture in POSTURES:
            probed = frame_as_rest(posed(motion, named[0], posture))
            assert standing_frames(probed, named[0]).mean() < 0.1, posture
            outcome = _outcome(named, probed)
            if outcome is None:
                alike += 1
                warnings = map_clip(probed).warnings
                assert any("no pose shows a standing figure" in w for w in warnings)
            elif not outcome.startswith("refused"):
                wrong[(shape, posture)] = outcome
    print(f"synthetic: {alike} of {len(SHAPES) * len(POSTURES)} map alike")
    assert not wrong, wrong
    assert alike >= RECORDED_SYNTHETIC


# Kneeling on one knee, held (a genuflection, a proposal): the left thigh forward and its
# shin down to the planted foot; the right thigh down to the knee on the floor and its shin
# back, the ankle raised (toes tucked under): that lower leg points back up the trunk a
# little, as no seated or crouched leg does. On main the take was refused (a lower leg not
# carrying the body had to point away from the head).
KNEELING = (("l_hip", -90.0), ("l_knee", 90.0), ("r_knee", 75.0))


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_a_take_kneeling_on_one_knee_maps_alike(fixture: str) -> None:
    motion = read_bvh(fixture_bytes(fixture))
    named = _named_mapping(motion)
    held = frames_at(motion, np.zeros(motion.frame_count, dtype=np.int64))  # frame 0, held
    probed = frame_as_rest(posed(held, named[0], KNEELING))
    assert _outcome(named, probed) is None
    assert any("no pose shows a standing figure" in w for w in map_clip(probed).warnings)


def _toe_moved(motion: Motion, names: tuple[str, ...], scale: float) -> Motion:
    """``motion`` with the left toe joint set ``scale`` times as far from its ankle (an
    auto-rigger placing each joint on its own side's mesh), the rest unchanged."""
    toe = _at(names, motion, "l_toe")
    while motion.skeleton.end_site[toe]:  # the toe joint, not the End Site beyond it
        toe = int(motion.skeleton.parents[toe])
    return bones_scaled(motion, [toe], scale)


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_a_seated_take_with_one_foot_bone_a_third_longer_maps_alike(fixture: str) -> None:
    """The legs are mirror images where their joints lie along them, not bone by bone: one
    foot bone 35 % longer (a sumo figure's Mixamo rig has 1.33 against 1.04) moves that
    joint a few hundredths of the leg. On main the seated take was refused (no legs)."""
    motion = read_bvh(fixture_bytes(fixture))
    names = _named_mapping(motion)[0]
    moved = _toe_moved(motion, names, 1.35)
    named = _named_mapping(moved)
    assert named[0] == names  # standing, the rig maps as before
    probed = frame_as_rest(posed(moved, names, "seated"))
    assert _outcome(named, probed) is None
