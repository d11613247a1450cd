"""A limb's straight runs in a rest pose with bent limbs (``app.motion.mapping.runs``;
docs/skeletons.md, "fourth pass"): MakeHuman's rig stands in an A-pose with the elbows bent
and a twist bone halving the forearm, and its thigh starts with a short bone turned forward.
Without names, structure alone must find the joints the names say."""

from __future__ import annotations

import pytest

from app.motion.formats import read_bvh
from app.motion.pipeline import describable_body
from app.motion.skeleton_map import CANONICAL_JOINTS
from tests.conftest import shared_data_dir
from tests.motion.test_mapping_pairs import nameless

MAKEHUMAN = shared_data_dir() / "wild-bvh" / "makehuman" / "standing01.bvh"


@pytest.mark.skipif(not MAKEHUMAN.is_file(), reason=f"no {MAKEHUMAN}")
def test_a_bent_elbow_a_forearm_twist_and_a_first_thigh_bone_without_names() -> None:
    motion = read_bvh(MAKEHUMAN.read_bytes())
    names = motion.skeleton.names
    bare = describable_body(nameless(motion)).mapping
    assert bare is not None
    found = {c: names[int(j)] for c, j in zip(CANONICAL_JOINTS, bare.joints, strict=True)}
    for side in "LR":
        s = side.lower()
        # The run ending at the wrist is the forearm alone: its top is the elbow.
        assert found[f"{s}_shoulder"] == f"upperarm01.{side}"
        assert found[f"{s}_elbow"] == f"lowerarm01.{side}"
        assert found[f"{s}_wrist"] == f"wrist.{side}"
        # The thigh's first bone turns forward, not outward: the hip is above it.
        assert found[f"{s}_hip"] == f"upperleg01.{side}"
        assert found[f"{s}_knee"] == f"lowerleg01.{side}"


@pytest.mark.skipif(not MAKEHUMAN.is_file(), reason=f"no {MAKEHUMAN}")
def test_the_named_makehuman_rig_maps_as_its_names_say() -> None:
    motion = read_bvh(MAKEHUMAN.read_bytes())
    named = describable_body(motion).mapping
    bare = describable_body(nameless(motion)).mapping
    assert named is not None and bare is not None
    assert list(named.joints) == list(bare.joints)
