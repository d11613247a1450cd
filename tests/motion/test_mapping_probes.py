"""What an unseen exporter plausibly does to a rig we know, and the mapping must survive:
another rest pose for the same motion (the first frame as rest, every bone in axes of its
own), clavicles left out, twist bones inside limb bones, the children in another order,
millimetres, a still stretch in the take. Forward kinematics gives the same positions in
every case (checked), so the same source joints must be found, by name (issue 20,
"generalisation probes"; docs/skeletons.md, "Probes").

On the real CMU and Bandai excerpts in tests/fixtures, and, where ../shared is present, on
every human BVH of the development sets: the probes every rig passes are asserted for each;
the rest-pose probes are ratchets that say which rigs fail.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import MocapError
from app.motion import transforms
from app.motion.descriptors import REGISTRY
from app.motion.formats import read_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.windows import describe_windows
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.holds import held_motion
from tests.motion.read_once import read_only
from tests.motion.test_nameless_real import FILES

Probe = Callable[[Motion], Motion]


def _translations(motion: Motion) -> np.ndarray:
    """``(F, J, 3)`` every joint's offset from its parent, per frame."""
    if motion.local_translations is not None:
        return motion.local_translations.copy()
    offsets = motion.skeleton.offsets
    return np.broadcast_to(offsets, (motion.frame_count, *offsets.shape)).copy()


def _rebuilt(
    motion: Motion,
    parents: list[int],
    offsets: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    names: list[str],
    end_site: list[bool],
    rng: np.random.Generator | None = None,
) -> Motion:
    """A motion of the joints given (any order, ``-1`` for dropped joints' rows is not
    allowed: pass only kept joints), written parents first; siblings in ``rng``'s order when
    given (an exporter that lists children otherwise), else in index order."""
    count = len(parents)
    children: list[list[int]] = [[] for _ in range(count)]
    for j, p in enumerate(parents):
        if p >= 0:
            children[p].append(j)
    order: list[int] = []
    stack = [parents.index(-1)]
    while stack:
        j = stack.pop()
        order.append(j)
        kids = list(children[j])
        if rng is not None:
            rng.shuffle(kids)
        stack.extend(reversed(kids))
    at = np.empty(count, dtype=np.int64)
    at[order] = np.arange(count)
    skeleton = Skeleton(
        tuple(names[j] for j in order),
        np.array([-1 if parents[j] < 0 else int(at[parents[j]]) for j in order]),
        np.asarray(offsets, dtype=float)[order],
        np.asarray(end_site, dtype=bool)[order],
    )
    return dataclasses.replace(
        motion,
        skeleton=skeleton,
        local_rotations=np.ascontiguousarray(rotations[:, order]),
        local_translations=None
        if motion.local_translations is None
        else np.ascontiguousarray(translations[:, order]),
    )


def _arrays(motion: Motion) -> tuple[list[int], np.ndarray, np.ndarray, np.ndarray, list, list]:
    skeleton = motion.skeleton
    return (
        [int(p) for p in skeleton.parents],
        skeleton.offsets.copy(),
        motion.local_rotations.copy(),
        _translations(motion),
        list(skeleton.names),
        [bool(e) for e in skeleton.end_site],
    )


def shuffled(motion: Motion, seed: int = 0) -> Motion:
    """Every joint's children listed in another order."""
    return _rebuilt(motion, *_arrays(motion), rng=np.random.default_rng(seed))


def twist_inside(motion: Motion, child: int) -> Motion:
    """A joint half-way along the bone that ends at ``child`` (a twist bone, no motion of
    its own: identity rotation)."""
    parents, offsets, rotations, translations, names, end_site = _arrays(motion)
    frames = motion.frame_count
    parents.append(parents[child])
    parents[child] = len(parents) - 1
    offsets = np.concatenate([offsets, 0.5 * offsets[child][None]])
    offsets[child] *= 0.5
    translations = np.concatenate([translations, 0.5 * translations[:, child][:, None]], axis=1)
    translations[:, child] *= 0.5
    rotations = np.concatenate([rotations, np.broadcast_to(np.eye(3), (frames, 1, 3, 3))], axis=1)
    return _rebuilt(
        motion, parents, offsets, rotations, translations, [*names, "twist"], [*end_site, False]
    )


def without(motion: Motion, joint: int) -> Motion:
    """``joint`` left out: its children hang from its parent and move as before."""
    parents, offsets, rotations, translations, names, end_site = _arrays(motion)
    for child in [c for c, p in enumerate(parents) if p == joint]:
        translations[:, child] = translations[:, joint] + np.einsum(
            "fab,fb->fa", rotations[:, joint], translations[:, child]
        )
        rotations[:, child] = rotations[:, joint] @ rotations[:, child]
        offsets[child] = offsets[joint] + offsets[child]
        parents[child] = parents[joint]
    keep = [j for j in range(len(parents)) if j != joint]
    return kept(motion, keep, (parents, offsets, rotations, translations, names, end_site))


def kept(motion: Motion, keep: list[int], arrays: tuple) -> Motion:
    """The motion of the joints ``keep`` of ``arrays`` (as :func:`_arrays` gives them, maybe
    changed; each kept joint's parent kept too), written parents first."""
    parents, offsets, rotations, translations, names, end_site = arrays
    index = {old: new for new, old in enumerate(keep)}
    return _rebuilt(
        motion,
        [-1 if parents[j] < 0 else index[parents[j]] for j in keep],
        offsets[keep],
        rotations[:, keep],
        translations[:, keep],
        [names[j] for j in keep],
        [end_site[j] for j in keep],
    )


def rebased(motion: Motion, frames: np.ndarray) -> Motion:
    """The same motion with joint j's local axes turned by the constant ``(J, 3, 3)``
    ``frames[j]``: offsets ``C_p^T o``, rotations ``C_p^T R C_j``; positions unchanged, the
    rest pose of the offsets another one."""
    skeleton = motion.skeleton
    parent_frames = np.stack(
        [np.eye(3) if p < 0 else frames[p] for p in skeleton.parents]
    )  # (J, 3, 3)
    rotations = np.einsum("jba,fjbc,jcd->fjad", parent_frames, motion.local_rotations, frames)
    rotations[:, 0] = motion.local_rotations[:, 0] @ frames[0]
    offsets = np.einsum("jba,jb->ja", parent_frames, skeleton.offsets)
    translations = (
        None
        if motion.local_translations is None
        else np.einsum("jba,fjb->fja", parent_frames, motion.local_translations)
    )
    return dataclasses.replace(
        motion,
        skeleton=dataclasses.replace(skeleton, offsets=offsets),
        local_rotations=rotations,
        local_translations=translations,
    )


def _world_rotations(motion: Motion, frame: int) -> np.ndarray:
    rotations = motion.local_rotations[frame]
    world = np.empty_like(rotations)
    for j, p in enumerate(motion.skeleton.parents):
        world[j] = rotations[j] if p < 0 else world[p] @ rotations[j]
    return world


def frame_as_rest(motion: Motion, frame: int = 0) -> Motion:
    """The rig as a writer that takes ``frame`` for its rest pose writes it (each joint's
    axes are its world axes at that frame: every rotation there is the root's only)."""
    return rebased(motion, np.transpose(_world_rotations(motion, frame), (0, 2, 1)))


def own_axes(motion: Motion, seed: int = 0) -> Motion:
    """Every bone in local axes of its own (a rest pose that is no standing figure)."""
    turns = Rotation.random(motion.skeleton.joint_count, random_state=seed).as_matrix()
    return rebased(motion, turns)


def _named_mapping(motion: Motion) -> tuple[tuple[str, ...], bool]:
    mapping = describable_body(motion).mapping
    assert mapping is not None
    return tuple(motion.skeleton.names[j] for j in mapping.joints), mapping.mirrored


def _joint(motion: Motion, names: tuple[str, ...], canonical: str) -> int:
    return motion.skeleton.names.index(names[CANONICAL_INDEX[canonical]])


def _probes(motion: Motion, names: tuple[str, ...] | None = None) -> dict[str, Probe]:
    """Name -> perturbation of ``motion`` (the clavicles only where the rig has them);
    ``names``: the rig's mapped joint names when already known."""
    if names is None:
        names, _ = _named_mapping(motion)
    probes: dict[str, Probe] = {
        "z-up": lambda m: transforms.change_basis(
            m, transforms.rotation_about([1.0, 0.0, 0.0], 90.0)
        ),
        "x-forward": lambda m: transforms.change_basis(
            m, transforms.rotation_about([0.0, 1.0, 0.0], 90.0)
        ),
        "millimetres": lambda m: transforms.rescale(m, 1000.0),
        "children shuffled": shuffled,
        "twist bones in upper arm and shin": lambda m: twist_inside(
            twist_inside(m, _joint(m, names, "l_elbow")), _joint(m, names, "r_ankle")
        ),
        "still 2 s in the middle": lambda m: held_motion(m, m.frame_count // 2, 240),
        "first frame as rest": frame_as_rest,
        "bones in axes of their own": own_axes,
    }
    parents = motion.skeleton.parents
    collars = sorted(
        {int(parents[_joint(motion, names, f"{side}_shoulder")]) for side in "lr"}, reverse=True
    )
    if _joint(motion, names, "chest") not in collars:
        probes["clavicles left out"] = lambda m: without(without(m, collars[0]), collars[1])
    return probes


REST_PROBES = ("first frame as rest", "bones in axes of their own")
# Probes that change how the motion is written and not where a joint is.
SAME_POSITIONS = (
    "children shuffled",
    "twist bones in upper arm and shin",
    "clavicles left out",
    *REST_PROBES,
)


def _check_same_positions(before: Motion, after: Motion) -> None:
    """The probe changed how the motion is written, not where the joints are."""
    _, a = forward_kinematics(before)
    _, b = forward_kinematics(after)
    kept = [n for n in before.skeleton.names if n in after.skeleton.names]
    were = [before.skeleton.names.index(n) for n in kept]
    now = [after.skeleton.names.index(n) for n in kept]
    np.testing.assert_allclose(b[:, now], a[:, were], atol=1e-6 * np.ptp(a))


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_the_fixtures_map_alike_under_every_probe(fixture: str) -> None:
    motion = read_bvh(fixture_bytes(fixture))
    named = _named_mapping(motion)
    for name, probe in _probes(motion, named[0]).items():
        changed = probe(motion)
        if name in SAME_POSITIONS:
            _check_same_positions(motion, changed)
        assert _named_mapping(changed) == named, name


@functools.cache
def _dev_rig(path: Path) -> tuple[Motion, tuple[tuple[str, ...], bool], dict[str, Probe]]:
    """A dev file parsed and mapped once for every probe (read-only: each probe copies)."""
    motion = read_only(read_bvh(path.read_bytes()))
    named = _named_mapping(motion)
    return motion, named, _probes(motion, named[0])


def _outcomes(probe: str) -> dict[str, str | None]:
    """Dev file -> None when the probed copy maps like the file, else how not."""
    found: dict[str, str | None] = {}
    for path in FILES:
        motion, named, probes = _dev_rig(path)
        if probe not in probes:
            continue
        try:
            got = _named_mapping(probes[probe](motion))
        except MocapError as error:
            found[path.name] = f"refused: {error}"
            continue
        pairs = [(a, b) for a, b in zip(named[0], got[0], strict=True) if a != b]
        found[path.name] = None if got == named else f"differ {pairs}, mirrored {got[1]}"
    return found


# Probes every human BVH of the development sets passes.
EVERY_RIG = (
    "z-up",
    "x-forward",
    "millimetres",
    "children shuffled",
    "twist bones in upper arm and shin",
    "still 2 s in the middle",
    "clavicles left out",
)
# Rest-pose probes: human BVH files whose probed copy maps alike, at least (a ratchet).
# (59 and 61 before a single pose on one leg was read, 2026-11-27; 62 and 62 before the
# take's deepest knee bends decided over its mild ones, 2026-11-29.)
RECORDED = {"first frame as rest": 63, "bones in axes of their own": 63}


@pytest.mark.skipif(not FILES, reason="no wild-bvh or wild-more in ../shared/data")
@pytest.mark.parametrize("probe", EVERY_RIG)
def test_every_human_dev_rig_maps_alike_under_the_probe(probe: str) -> None:
    outcomes = _outcomes(probe)
    assert not any(outcomes.values()), {k: v for k, v in outcomes.items() if v}


@pytest.mark.skipif(not FILES, reason="no wild-bvh or wild-more in ../shared/data")
@pytest.mark.parametrize("probe", REST_PROBES)
def test_human_dev_rigs_under_another_rest_pose(probe: str) -> None:
    outcomes = _outcomes(probe)
    same = sum(v is None for v in outcomes.values())
    print(f"{probe}: {same} of {len(outcomes)} map alike")
    assert same >= RECORDED[probe], {k: v for k, v in outcomes.items() if v}


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
@pytest.mark.parametrize("extra", [1, 37, 240])
def test_a_still_stretch_written_into_the_file_changes_nothing_but_the_still_part(
    fixture: str, extra: int
) -> None:
    """The held frames go through everything a file goes through (the mapping from the
    frames the mapper reads, the lead-in, the body's frame, the height), not only the
    descriptors: the mapping is the same and every window that ends by the held frame, or
    starts at it or later (``extra`` frames later in the longer take), is the same window."""
    motion = read_bvh(fixture_bytes(fixture))
    at = motion.frame_count // 2
    body = describable_body(motion)
    longer = describable_body(held_motion(motion, at, extra))
    assert body.mapping is not None and longer.mapping is not None
    np.testing.assert_array_equal(longer.mapping.joints, body.mapping.joints)
    assert longer.lead_in_frames == body.lead_in_frames
    at -= body.lead_in_frames  # body frames
    frames = body.frame_count
    spans = np.array(
        [[0, s, e] for s, e in [(0, at + 1), (max(0, at - 10), at + 1), (at, frames)]]
        + [[0, s, min(frames, s + 12)] for s in range(at, frames - 1, 7)]
    )
    moved = spans.copy()
    moved[:, 1:] += np.where(spans[:, 1:2] >= at, extra, 0)
    names = list(REGISTRY)
    original = describe_windows(body, spans, names)
    again = describe_windows(longer, moved, names)
    for name in names:
        np.testing.assert_allclose(again[name], original[name], rtol=1e-5, atol=1e-5, err_msg=name)
