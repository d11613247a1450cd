"""The shoulders on a bone of their own beside the neck (app/motion/mapping/hypotheses.py,
``_girdle_top``; issue 20, held-out round 13): a BVH writer hangs both collars from a joint
(``Chest2``) that branches off the spine beside the neck, which leaves the spine joint
below it. Nothing but the arms leaves the joint where they part, and a head was looked for
only there: the file was refused "no head". The chest is where the arms part; the head is
the spine's other branch, and still rises above the shoulders."""

from __future__ import annotations

import numpy as np
import pytest

from app.errors import SkeletonMappingError
from app.motion.formats import read_bvh
from app.motion.model import Motion
from app.motion.pipeline import analyse
from bench.probe_mapping import mapped_names, shoulders_on_a_branch
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes
from tests.motion.skeleton_trees import Humanoid, synthetic_humanoid
from tests.motion.synthetic import below, grown, walking
from tests.motion.test_mapping_probes import _arrays, kept


def _mapped(motion: Motion) -> dict[str, str]:
    analysis = analyse(motion)
    assert all(np.isfinite(v).all() for v in analysis.descriptors.values())
    return {c: place["joint"] for c, place in analysis.joint_mapping["joints"].items()}


@pytest.mark.parametrize("fixture", [CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def test_shoulders_on_a_bone_beside_the_neck_map_as_the_plain_rig(fixture: str) -> None:
    """On the code before, refused: "no head: nothing but the two arms leaves the joint
    where they branch off"."""
    motion = read_bvh(fixture_bytes(fixture))
    expected, _ = mapped_names(motion)
    girdled, moved = shoulders_on_a_branch(motion, dict(expected))
    assert moved["chest"] == "shoulders_branch"
    assert _mapped(girdled) == moved


def test_a_branch_that_stays_below_the_shoulders_is_no_head() -> None:
    """The spine's other branch is a head only where it rises above the shoulders: a rig
    with its shoulders on a bone of their own, its head cut, and a short chain up the back
    from the spine joint below them, ending above that joint but below the shoulders' bone
    (a tail, a prop's strap), is refused."""
    rig, truth = synthetic_humanoid(Humanoid(names="unity"))
    motion = walking(rig, truth)
    expected, _ = mapped_names(motion)
    girdled, moved = shoulders_on_a_branch(motion, dict(expected))
    names = list(girdled.skeleton.names)
    neck = names.index(moved["neck"])
    parents, offsets, _, translations, _, _ = arrays = _arrays(girdled)
    # The shoulders' bone raised 0.15 m up the spine, the arms where they were.
    branch = names.index("shoulders_branch")
    lift = np.array([0.0, 0.15, 0.0])
    offsets[branch] += lift
    translations[:, branch] += lift
    for arm in [j for j, parent in enumerate(parents) if parent == branch]:
        offsets[arm] -= lift
        translations[:, arm] -= lift
    cut = {neck, *below(girdled.skeleton, neck)}
    headless = kept(girdled, [j for j in range(len(names)) if j not in cut], arrays)
    skeleton = headless.skeleton
    # Each bone of the strap: 0.04 m up and as much back, its end below the shoulders' bone.
    bone = np.array([0.0, 0.04, -0.04])
    strap = grown(
        headless,
        [int(skeleton.parents[skeleton.names.index("shoulders_branch")]), skeleton.joint_count],
        [bone, bone],
    )
    with pytest.raises(SkeletonMappingError):
        analyse(strap)
