"""What must not change the canonical body: names, extra joints, axes, units; and a mirrored
capture must be recognised and undone. On the real CMU and Bandai excerpts in tests/fixtures."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from app.motion import transforms
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import ClipAnalysis, analyse
from app.motion.skeleton_map import CANONICAL_INDEX, map_skeleton
from tests.motion.conftest import (
    BANDAI_FIXTURE,
    CMU_AMC_FIXTURE,
    CMU_ASF_FIXTURE,
    CMU_BVH_FIXTURE,
    FIXTURES_DIR,
    fixture_bytes,
)
from tests.motion.shared import SHARED_DATA, requires_shared_data
from tests.motion.skeleton_trees import (
    SHORT_GAME_RIG,
    Humanoid,
    skeleton_from_points,
    synthetic_humanoid,
)
from tests.motion.synthetic import grown, walking, with_cloth_chains

FIXTURES = (CMU_BVH_FIXTURE, BANDAI_FIXTURE)


def _motion(name: str) -> Motion:
    return read_bvh(fixture_bytes(name))


def _same(a: ClipAnalysis, b: ClipAnalysis, atol: float = 1e-6) -> None:
    for name, vector in a.descriptors.items():
        np.testing.assert_allclose(b.descriptors[name], vector, atol=atol, err_msg=name)


def _renamed(motion: Motion) -> Motion:
    skeleton = motion.skeleton
    names = tuple(f"j{i}" for i in range(skeleton.joint_count))
    return dataclasses.replace(
        motion, skeleton=Skeleton(names, skeleton.parents, skeleton.offsets, skeleton.end_site)
    )


def _cmu_asf() -> Motion:
    return read_asf_amc(fixture_bytes(CMU_ASF_FIXTURE), fixture_bytes(CMU_AMC_FIXTURE))


@pytest.mark.parametrize("load", [lambda: _motion(CMU_BVH_FIXTURE), _cmu_asf], ids=["bvh", "asf"])
def test_meaningless_names_keep_mapping_and_descriptors(load):
    # The CMU rigs are unambiguous: sides from the feet, joints from the shape (the ASF's
    # collar bones run almost in line with its T-posed arms: proportions tell them apart).
    motion = load()
    named, anonymous = analyse(motion), analyse(_renamed(motion))
    np.testing.assert_array_equal(anonymous.body.mapping.joints, named.body.mapping.joints)
    _same(named, anonymous)
    assert anonymous.warnings == ()


@pytest.mark.parametrize("fixture", FIXTURES)
@pytest.mark.parametrize("axis", [0, 2])
def test_a_mirrored_capture_is_recognised_and_undone(fixture: str, axis: int):
    # Reflected geometry with the names kept: the limbs called left lie on the right.
    motion = _motion(fixture)
    original = analyse(motion)
    mirrored = analyse(transforms.reflect(motion, axis=axis))
    assert mirrored.body.mapping.mirrored is True
    assert "mirrored capture: stored un-mirrored" in mirrored.warnings
    assert original.body.mapping.mirrored is False
    _same(original, mirrored)


def _with_extra_leaves(motion: Motion, count: int, seed: int = 3) -> Motion:
    """``count`` extra leaf joints as real rigs carry them: twist bones inside limb bones,
    short face/finger-like leaves, IK targets and props hanging from the root, all without
    motion of their own."""
    skeleton = motion.skeleton
    rng = np.random.default_rng(seed)
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    scale = float(lengths.max())
    movable = [j for j in range(skeleton.joint_count) if not skeleton.end_site[j]]
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    for i in range(count):
        kind = i % 3
        if kind == 0:  # a twist bone half-way along a bone
            bones = [j for j in movable if j > 0 and lengths[j] > 0]
            child = int(rng.choice(bones))
            parent, offset = int(skeleton.parents[child]), 0.5 * skeleton.offsets[child]
        elif kind == 1:  # a short leaf (face, finger nub, helper)
            parent = int(rng.choice(movable))
            offset = rng.normal(size=3) * 0.02 * scale
        else:  # an IK target or prop under the root, somewhere about the body
            parent, offset = 0, rng.normal(size=3) * scale
        parents.append(parent)
        offsets.append(np.asarray(offset, dtype=float))
    return grown(motion, parents, offsets)


def _with_small_bones(motion: Motion, count: int, seed: int = 5) -> Motion:
    """``count`` small extra bones where real rigs carry them (a Bitmoji-like face, Blender
    finger end bones): chains of one to three bones on the head, the hands and the feet, each
    chain shorter than the part it hangs from reaches already (so the head top, fingertips
    and toes stay where they are)."""
    mapping = analyse(motion).body.mapping
    assert mapping is not None
    skeleton = motion.skeleton
    reach = _reach(skeleton)
    rng = np.random.default_rng(seed)
    parts = [
        int(mapping.joints[CANONICAL_INDEX[f"{side}_{part}"]])
        for side in ("l", "r")
        for part in ("wrist", "ankle")
    ]
    # A hand without bones gains none (fingers would be a hand, a new hand tip).
    hangs = [mapping.head_joint] * 6 + [j for j in parts if reach[j] > 0]
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    while len(parents) < count:
        top = hangs[len(parents) % len(hangs)]
        bones = int(rng.integers(1, 4))
        size = 0.3 * max(reach[top], 1e-9) / bones  # the whole chain within 30 % of it
        parent = top
        for _ in range(min(bones, count - len(parents))):
            step = rng.normal(size=3)
            parents.append(parent)
            offsets.append(step / np.linalg.norm(step) * size * rng.uniform(0.3, 1.0))
            parent = skeleton.joint_count + len(parents) - 1
    return grown(motion, parents, offsets)


def _reach(skeleton: Skeleton) -> np.ndarray:
    """``(J,)`` longest bone path from each joint down to a descendant. An End Site exactly as
    long as the bone it ends is a tail a writer invented, no point of the body (the mapper
    does not read it, docs/skeletons.md): counted, it doubled a Mixamo BVH head's reach, and
    face chains grew past the head's top."""
    lengths = np.linalg.norm(skeleton.offsets, axis=1)
    parent_lengths = lengths[np.maximum(skeleton.parents, 0)]
    invented = skeleton.end_site & (np.abs(lengths - parent_lengths) <= 1e-4 * parent_lengths)
    lengths[invented] = 0.0
    reach = np.zeros(skeleton.joint_count)
    for j in range(skeleton.joint_count - 1, 0, -1):
        p = int(skeleton.parents[j])
        reach[p] = max(reach[p], reach[j] + lengths[j])
    return reach


def _anonymous_walker() -> Motion:
    skeleton, truth = synthetic_humanoid(Humanoid(names="anon", hand="bone"))
    return walking(skeleton, truth)


@pytest.mark.parametrize(
    "load",
    [
        lambda: _motion(CMU_BVH_FIXTURE),
        lambda: _motion(BANDAI_FIXTURE),
        lambda: _renamed(_motion(CMU_BVH_FIXTURE)),
        _anonymous_walker,
    ],
    ids=["cmu", "bandai", "cmu-no-names", "synthetic-no-names"],
)
def test_a_rig_with_150_extra_small_leaf_bones_maps_like_the_plain_rig(load):
    motion = load()
    plain, busy = analyse(motion), analyse(_with_small_bones(motion, 150))
    np.testing.assert_array_equal(busy.body.mapping.joints, plain.body.mapping.joints)
    assert busy.warnings == plain.warnings
    _same(plain, busy)


@pytest.mark.parametrize("load", [lambda: _motion(CMU_BVH_FIXTURE), _cmu_asf], ids=["bvh", "asf"])
def test_hair_and_cloth_chains_as_long_as_limbs_change_no_joint(load):
    """A character rig's hair strands hang from the head as far as the waist (VRoid's, a
    ponytail), its skirt from the pelvis: chains as long as an arm, which the five farthest
    ends of the tree then include. A strand taken for the head's end leaves the head's top
    where the skull is (before, the strand's end was below the chest, that choice failed,
    and a hair chain was taken for an arm, an arm for the head). On rigs whose rest pose is
    a T-pose, where the cloth is placed."""
    motion = load()
    plain = analyse(motion)
    mapping = plain.body.mapping
    assert mapping is not None
    joint = {
        c: int(mapping.joints[CANONICAL_INDEX[c]]) for c in ("chest", "pelvis", "l_hip", "r_hip")
    }
    dressed = with_cloth_chains(
        motion,
        mapping.head_joint,
        joint["chest"],
        joint["pelvis"],
        (joint["l_hip"], joint["r_hip"]),
    )
    busy = analyse(dressed)
    assert busy.body.mapping is not None
    np.testing.assert_array_equal(busy.body.mapping.joints, mapping.joints)
    assert busy.warnings == plain.warnings
    _same(plain, busy)


@pytest.mark.parametrize("fixture", FIXTURES)
def test_fifty_extra_leaf_joints_change_nothing(fixture: str):
    motion = _motion(fixture)
    plain, busy = analyse(motion), analyse(_with_extra_leaves(motion, 50))
    np.testing.assert_array_equal(busy.body.mapping.joints, plain.body.mapping.joints)
    _same(plain, busy)


def test_joints_a_hair_off_their_parent_map_as_joints_on_it():
    """The CMU ASF spine (``lowerback`` sits on the root) after a round trip through another
    tool's float rounding (an FBX export read back: 2e-8 of the body's size): the same
    mapping, not a spine one joint lower."""
    motion = _cmu_asf()
    offsets = motion.skeleton.offsets.copy()
    size = float(np.ptp(offsets.cumsum(axis=0), axis=0).max())
    on_parent = np.flatnonzero(np.linalg.norm(offsets, axis=1) == 0)[1:]
    assert len(on_parent), "the fixture has joints on their parents"
    offsets[on_parent] = 2e-8 * size * np.array([1.0, -0.1, 0.02])
    rounded = dataclasses.replace(
        motion, skeleton=dataclasses.replace(motion.skeleton, offsets=offsets)
    )
    plain = map_skeleton(motion.skeleton)
    np.testing.assert_array_equal(map_skeleton(rounded.skeleton).joints, plain.joints)


@pytest.mark.parametrize("fixture", FIXTURES)
def test_z_up_and_inches_change_nothing(fixture: str):
    motion = _motion(fixture)
    plain = analyse(motion)
    # Y-up -> Z-up: the file as a Z-up exporter writes it, rest pose included.
    z_up = transforms.change_basis(motion, transforms.rotation_about([1.0, 0.0, 0.0], 90.0))
    inches = transforms.rescale(motion, 1.0 / 0.0254 / 100.0)  # centimetre-like -> inches
    for changed in (analyse(z_up), analyse(inches)):
        np.testing.assert_array_equal(changed.body.mapping.joints, plain.body.mapping.joints)
        _same(plain, changed, atol=1e-5)


def test_names_against_the_geometry_on_one_pair_lose_with_a_warning():
    # The leg chains' names swapped (a converter's mix-up), the arms' kept: no mirror can
    # explain it, so the geometry decides and says so.
    motion = _motion(CMU_BVH_FIXTURE)
    swap = {"Left": "Right", "Right": "Left", "LHip": "RHip", "RHip": "LHip"}
    legs = ("HipJoint", "UpLeg", "Leg", "Foot", "ToeBase")

    def swapped(name: str) -> str:
        for word, other in swap.items():
            if name.startswith(word) and name[len(word) :].split("_")[0] in legs:
                return other + name[len(word) :]
        return name

    names = tuple(swapped(n) for n in motion.skeleton.names)
    assert names != motion.skeleton.names
    confused = analyse(
        dataclasses.replace(
            motion,
            skeleton=Skeleton(
                names, motion.skeleton.parents, motion.skeleton.offsets, motion.skeleton.end_site
            ),
        )
    )
    np.testing.assert_array_equal(confused.body.mapping.joints, analyse(motion).body.mapping.joints)
    assert confused.body.mapping.mirrored is False
    assert any("sides taken from the geometry" in w for w in confused.warnings)


def _mapping_of_frames(motion: Motion, first: int, stop: int) -> tuple[list[int], bool]:
    mapping = analyse(motion.slice_frames(first, stop)).body.mapping
    return mapping.joints.tolist(), mapping.mirrored


def _cuts(frame_count: int, length: int) -> list[tuple[int, int]]:
    return [(start, start + length) for start in range(0, frame_count - length + 1, length // 2)]


def test_every_part_of_a_clip_gets_the_clip_s_mapping():
    # The Bandai rig's rest pose is no standing figure: its mapping comes from frames. One
    # frame of a walk can put the feet or knees anywhere; the sides must not follow it.
    motion = _motion(BANDAI_FIXTURE)
    whole = _mapping_of_frames(motion, 0, motion.frame_count)
    assert not whole[1]
    for first, stop in _cuts(motion.frame_count, 12):
        assert _mapping_of_frames(motion, first, stop) == whole, (first, stop)


@requires_shared_data
def test_every_part_of_every_bandai_clip_gets_the_clip_s_mapping():
    """1-s parts of every Bandai dataset-1 clip (the moments a user cuts and searches with)
    map like their clip."""
    changed = []
    for path in sorted((SHARED_DATA / "bandai-ds1").rglob("*.bvh")):
        motion = read_bvh(path.read_bytes())
        whole = _mapping_of_frames(motion, 0, motion.frame_count)
        size = round(1.0 / motion.frame_time)
        for first, stop in _cuts(motion.frame_count, size)[::3]:
            try:
                part = _mapping_of_frames(motion, first, stop)
            except Exception as error:  # a part may be refused; it must not be re-sided
                part = (type(error).__name__, False)  # type: ignore[assignment]
            if part != whole and part[0] != "SkeletonMappingError":
                changed.append(f"{path.stem} [{first}, {stop})")
    assert not changed, changed


def _leaves_as_joints(motion: Motion) -> Motion:
    """The motion as an FBX or glTF rig holds it: every leaf a joint of its own (a point
    without a tail), no End Sites."""
    skeleton = motion.skeleton
    return dataclasses.replace(
        motion,
        skeleton=Skeleton(
            skeleton.names,
            skeleton.parents,
            skeleton.offsets,
            np.zeros(skeleton.joint_count, dtype=bool),
        ),
    )


def _vrma() -> Motion:
    from app.motion.formats.gltf import read_gltf

    return read_gltf((FIXTURES_DIR / "three_vrm_test.vrma").read_bytes())[0]


@pytest.mark.parametrize(
    "load",
    [lambda: _leaves_as_joints(_motion(CMU_BVH_FIXTURE)), _vrma],
    ids=["leaf-joints", "vrma"],
)
def test_a_bvh_export_maps_like_its_source(load):
    # The BVH writer closes every leaf joint with a zero-length End Site: a point the rig
    # already had, which must not move a single canonical joint, nor the sides.
    motion = load()
    source = analyse(motion)
    exported = read_bvh(write_bvh(motion))
    assert exported.skeleton.joint_count > motion.skeleton.joint_count  # End Sites added
    again = analyse(exported)
    names = [motion.skeleton.names[j] for j in source.body.mapping.joints]
    assert [exported.skeleton.names[j] for j in again.body.mapping.joints] == names
    assert again.body.mapping.mirrored is source.body.mapping.mirrored is False
    _same(source, again, atol=1e-6)


def _with_end_sites(skeleton: Skeleton) -> Skeleton:
    """``skeleton`` with a zero-length End Site under every leaf, as the BVH writer adds."""
    leaves = [j for j in range(skeleton.joint_count) if j not in set(skeleton.parents.tolist())]
    return Skeleton(
        (*skeleton.names, *(f"{skeleton.names[j]}_end" for j in leaves)),
        np.concatenate([skeleton.parents, leaves]),
        np.concatenate([skeleton.offsets, np.zeros((len(leaves), 3))]),
        np.concatenate([skeleton.end_site, np.ones(len(leaves), dtype=bool)]),
    )


def test_zero_length_end_sites_change_no_joint_of_a_short_game_rig():
    # Legs ending in a ball joint reached going down: the zero-length End Site after it once
    # passed for a foot turning forward, and the legs' joints all moved one down.
    rig = skeleton_from_points(SHORT_GAME_RIG)
    plain, closed = map_skeleton(rig), map_skeleton(_with_end_sites(rig))
    assert [rig.names[j] for j in closed.joints] == [rig.names[j] for j in plain.joints]
    assert closed.mirrored is plain.mirrored is False
    assert rig.names[plain.joints[CANONICAL_INDEX["l_hip"]]] == "leg_L_1"
    assert rig.names[plain.joints[CANONICAL_INDEX["l_ankle"]]] == "leg_L_3"
