"""The pelvis's path over the floor (app/motion/retarget_floor.py): planted feet held, and
no travel the source does not have."""

from __future__ import annotations

import numpy as np

from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import Motion
from app.motion.retarget import retarget
from app.motion.retarget_floor import planted_feet_offsets, rig_foot_points
from app.motion.retarget_quality import retarget_quality
from app.motion.root_motion import in_place
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap
from bench.rig_variants import Draft
from tests.motion.conftest import BANDAI_FIXTURE, fixture_bytes
from tests.motion.test_retarget import mapped, rig_of

_UP = np.array([0.0, 1.0, 0.0])


def _strides(cycle: list[bool], cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """Source and target foot points ``(F, 4, 3)`` of a run in place: the left toe is on the
    floor (height 0) at the frames marked in ``cycle``, every point else 1 high; while the
    source's toe stands still, the target's slides forward 1 per frame (a longer foot
    rolling over its tip; in the air, where nothing is held, it stays)."""
    on = np.array(cycle * cycles)
    frames = len(on)
    source = np.zeros((frames, 4, 3))
    source[..., 1] = 1.0
    source[on, 1, 1] = 0.0
    target = source.copy()
    x = np.zeros(frames)
    for f in range(1, frames):
        x[f] = x[f - 1] + (1.0 if on[f] and on[f - 1] else 0.0)
    target[:, 1, 0] = x
    return source, target


def test_planted_feet_are_held_and_the_air_gives_the_correction_back() -> None:
    """Four frames on the toe, four in the air, five strides: the path holds the toe on the
    floor (moves back 1 per step on it) and returns in the air, so the take does not travel
    (before 2026-11-27 it went back 3 per stride, 15 in all)."""
    cycle = [True] * 4 + [False] * 4
    source, target = _strides(cycle, cycles=5)
    offsets = planted_feet_offsets(target, source, _UP, near=0.1)
    steps = np.diff(offsets[:, 0])
    on = np.array(cycle * 5)
    planted = on[1:] & on[:-1]
    np.testing.assert_allclose(steps[planted], -1.0)  # the toe held where the source's stands
    assert np.abs(steps).max() <= 1.0 + 1e-12  # no faster than the hold moved it
    np.testing.assert_allclose(offsets[on][::4, 0], 0.0, atol=1e-12)  # every contact from 0
    np.testing.assert_allclose(offsets[-1], 0.0, atol=1e-12)
    np.testing.assert_allclose(offsets[:, 1:], 0.0)  # horizontal only


def test_a_short_gap_in_a_long_contact_does_not_snap_the_body_back() -> None:
    """Twenty frames on the floor, one in the air, twenty more: each of the two steps through
    the air gives back no more than the largest correction of the contact (1), not all of
    the 19 gathered."""
    cycle = [True] * 20 + [False] + [True] * 20
    source, target = _strides(cycle, cycles=1)
    offsets = planted_feet_offsets(target, source, _UP, near=0.1)
    assert np.abs(np.diff(offsets[:, 0])).max() <= 1.0 + 1e-12


def test_a_single_frame_has_nothing_to_correct() -> None:
    source, target = _strides([True], cycles=1)
    np.testing.assert_array_equal(planted_feet_offsets(target, source, _UP, near=0.1), 0.0)


def test_an_in_place_run_on_a_long_footed_rig_stays_in_place(shared_data) -> None:
    """CMU's run ``02_03`` made in place (``root=in-place``) onto the Mixamo rig (a foot to
    the toe tip, long for its legs): before 2026-11-27 it travelled 0.084 leg lengths per
    second (the source: none), the holds' corrections summed over every contact. Now it
    stays within 0.005, and the issue's bars (sliding, feet, directions) still hold."""
    run_path = shared_data("cmu", "asf-amc", "02", "02_03.amc")
    rig_path = shared_data("wild-bvh", "mixamo", "ortiz_thankful.bvh")
    run = read_asf_amc((run_path.parent / "02.asf").read_bytes(), run_path.read_bytes())
    source = in_place(run, mapped(run))
    rig, rig_map = rig_of(read_bvh(rig_path.read_bytes()))
    out = retarget(source, mapped(source), rig, rig_map)
    quality = retarget_quality(source, mapped(source), out, rig_map)
    assert quality.source_travel < 1e-6
    assert quality.travel < 0.005, quality
    assert quality.passes(), quality


def _without_toes(rig: Motion, mapping: SkeletonMap) -> tuple[Motion, SkeletonMap]:
    """``rig`` with everything below its ankles dropped: each leg ends at the ankle, as a
    video pose's 17 joints do (its canonical toe is then its ankle)."""
    draft = Draft.of(rig)
    drop: set[int] = set()
    for side in ("l", "r"):
        ankle = int(mapping.joints[CANONICAL_INDEX[f"{side}_ankle"]])
        for child in (j for j, p in enumerate(draft.parents) if p == ankle):
            drop.update(draft.below(child))
    for joint in sorted(drop, reverse=True):
        draft.remove(joint)
    return draft.rig()


def test_a_rig_without_toes_keeps_the_walks_travel_and_its_ankles_move_as_the_sources() -> None:
    """The Bandai walk onto its own rig with the toes cut off. Before 2026-11-28 the rig's
    ankle (its canonical toe) was held against the source's toe: still while the source's
    heel rose and its ankle rolled forward, so the body lost each step's roll — net travel
    1.33 against the source's 1.44 leg lengths per second over these 40 frames — and that
    ankle, measured as the rig's toe, slid 0.225 body heights per second against the
    source's 0.196. Held as the source's ankles, they move as the source's do."""
    clip = read_bvh(fixture_bytes(BANDAI_FIXTURE))
    rig, rig_map = _without_toes(*rig_of(clip))
    assert rig_foot_points(rig_map) == [0, 2]  # the two ankles only
    out = retarget(clip, mapped(clip), rig, rig_map)
    quality = retarget_quality(clip, mapped(clip), out, rig_map)
    assert abs(quality.travel - quality.source_travel) < 1e-3 * quality.source_travel, quality
    assert quality.passes(), quality
