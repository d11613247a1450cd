"""Retargeting onto rigs from exporters we have not seen (app/motion/retarget.py, issue 22).

The rigs are the fixtures' own, rewritten as other exporters write rigs
(``bench/rig_variants.py``, the rewrites ``bench/eval_retarget.py generalise`` sweeps).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.motion.body import build_body
from app.motion.formats import read_bvh
from app.motion.ground import canonical_positions
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.retarget import reference_pose, retarget
from app.motion.retarget_quality import LIMB_BONES, retarget_quality
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap, map_skeleton
from bench.rig_variants import VARIANTS, Draft, unseen_variants
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.synthetic import walker_motion


def mapped(motion: Motion) -> SkeletonMap:
    body = build_body(motion)
    assert body.mapping is not None
    return body.mapping


def rig_of(motion: Motion) -> tuple[Motion, SkeletonMap]:
    rig = reference_pose(motion, mapped(motion))
    _, positions = forward_kinematics(rig)
    return rig, map_skeleton(rig.skeleton, poses=[("frame 0", positions[0])])


def degrees_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees between ``(..., 3)`` directions."""
    cos = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def split_limbs(rig: Motion, mapping: SkeletonMap, fraction: float) -> Draft:
    """``rig`` with each upper arm, forearm, thigh and shin split in two at ``fraction``
    of its length (a twist joint)."""
    draft = Draft.of(rig)
    for side in ("l", "r"):
        for top, end in (
            ("shoulder", "elbow"),
            ("elbow", "wrist"),
            ("hip", "knee"),
            ("knee", "ankle"),
        ):
            base = int(mapping.joints[CANONICAL_INDEX[f"{side}_{top}"]])
            tip = int(mapping.joints[CANONICAL_INDEX[f"{side}_{end}"]])
            at = draft.positions[base] + fraction * (draft.positions[tip] - draft.positions[base])
            draft.parents[tip] = draft.add(f"{draft.names[base]}_twist", base, at)
    return draft


def test_a_limb_split_at_other_points_than_the_sources_keeps_its_direction() -> None:
    walk = walker_motion(frames=120)
    rig, rig_map = rig_of(walk)
    on_quarter, on_quarter_map = split_limbs(rig, rig_map, 0.25).rig()
    on_three_quarters, three_quarters_map = split_limbs(rig, rig_map, 0.75).rig()
    # A clip on the rig split at a quarter whose twist joints also bend (up to 25 degrees,
    # about an axis across the bone): its pieces are not in line.
    source = retarget(walk, mapped(walk), on_quarter, on_quarter_map)
    local = source.local_rotations.copy()
    seconds = np.arange(source.frame_count) * source.frame_time
    for joint, name in enumerate(source.skeleton.names):
        if name.endswith("_twist"):
            child = list(source.skeleton.parents).index(joint)
            along = source.skeleton.offsets[child] / np.linalg.norm(source.skeleton.offsets[child])
            across = np.cross(along, [0.3, 0.5, 0.8])
            across /= np.linalg.norm(across)
            angle = np.radians(25.0) * np.sin(2 * np.pi * seconds)
            local[:, joint] = (
                local[:, joint] @ Rotation.from_rotvec(angle[:, None] * across).as_matrix()
            )
    source = dataclasses.replace(source, local_rotations=local)
    source_map = mapped(source)
    out = retarget(source, source_map, on_three_quarters, three_quarters_map)

    s = canonical_positions(source, source_map)
    t = canonical_positions(out, three_quarters_map)
    for a, b in LIMB_BONES:
        bone_s = s[:, CANONICAL_INDEX[b]] - s[:, CANONICAL_INDEX[a]]
        bone_t = t[:, CANONICAL_INDEX[b]] - t[:, CANONICAL_INDEX[a]]
        assert degrees_between(bone_s, bone_t).max() < 1e-5, (a, b)
    quality = retarget_quality(source, source_map, out, three_quarters_map)
    assert quality.direction_ok == 1.0
    assert quality.bone_error < 1e-9


def _fixture(name: str, seconds: float) -> Motion:
    motion = read_bvh(fixture_bytes(name))
    return motion.slice_frames(0, min(motion.frame_count, round(seconds / motion.frame_time)))


@pytest.mark.parametrize("rig_file", [BANDAI_FIXTURE, CMU_BVH_FIXTURE])
def test_every_kind_of_unseen_rig_takes_a_walk_within_the_bars(rig_file: str) -> None:
    clip = _fixture(CMU_BVH_FIXTURE if rig_file == BANDAI_FIXTURE else BANDAI_FIXTURE, 2.0)
    clip_map = mapped(clip)
    rig, rig_map = rig_of(read_bvh(fixture_bytes(rig_file)))
    variants = unseen_variants(rig, rig_map, seed=1)
    assert [kind for kind, _ in variants] == list(VARIANTS)
    for kind, draft in variants:
        target, target_map = draft.rig()
        out = retarget(clip, clip_map, target, target_map)
        quality = retarget_quality(clip, clip_map, out, target_map)
        assert out.skeleton.joint_count == target.skeleton.joint_count, kind
        assert quality.finite, kind
        assert quality.bone_error <= 1e-9, kind
        assert quality.left_ok == 1.0, kind
        assert quality.feet_error <= 0.02, kind
        assert quality.direction_ok >= 0.99, kind
        assert quality.slide <= quality.source_slide + 0.01, kind
