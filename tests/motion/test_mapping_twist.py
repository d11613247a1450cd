"""Twist bones hung along a limb (app/motion/mapping/tree.py ``_twist_leaves``): a leaf on
the line of a sibling bone and short of its end is no branch of the body. Game rigs hang
them half-way along the upper arm, forearm, thigh and shin (Unreal's mannequin); nameless,
a rig with a one-chain hand took the twist leaf's branch for the arm's root."""

from __future__ import annotations

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.mapping.tree import _twist_leaves
from app.motion.model import Motion, ParseLimits
from app.services.parser_pool import parse_scene
from bench.probe_mapping import mapped_names, nameless, outcome, twist_leaves


def test_only_a_leaf_along_a_longer_sibling_is_a_twist_leaf() -> None:
    #              root  arm        along   off-line       past the end   along, has child  child
    parents = np.array([-1, 0, 0, 0, 0, 0, 5])
    offsets = np.array(
        [[0, 0, 0], [1, 0, 0], [0.5, 0, 0], [0.5, 0.1, 0], [1.2, 0, 0], [0.4, 0, 0], [0, 1, 0]],
        dtype=float,
    )
    lengths = np.linalg.norm(offsets, axis=1)
    has_point = np.array([True, True, False, False, False, True, False])  # the arm goes on
    twist = _twist_leaves(parents, offsets, lengths, has_point)
    # Only joint 2 lies on the arm's line short of its end; 3 is 11 degrees off, 4 past the
    # arm's end (it is the longer one: the arm is not its twist), 5 has a bone below it.
    assert twist.tolist() == [False, False, True, False, False, False, False]


def _first_frames(motion: Motion) -> Motion:
    return motion.slice_frames(0, 300) if motion.frame_count > 300 else motion


@pytest.mark.parametrize(
    "folder, name",
    [
        ("wild-more/mixamo-fbx", "Redsumo101_Clapping.fbx"),  # a one-chain hand
        ("wild-more/mixamo-fbx", "michaelsteininger08_Jumping_Jacks.fbx"),
        ("wild-bvh/parser-breakers", "ammarkov_daz_cgspeed_crlf.bvh"),
    ],
)
def test_real_rigs_with_twist_leaves_and_no_names_map_alike(shared_data, folder, name) -> None:
    path = shared_data(*folder.split("/"), name)
    data = path.read_bytes()
    if path.suffix == ".bvh":
        motion = read_bvh(data)
    else:
        motion = parse_scene("fbx", data, None, ParseLimits()).motion
    motion = _first_frames(motion)
    expected, mirrored = mapped_names(motion)
    assert outcome(motion, expected, mirrored, [twist_leaves, nameless]) == "same"
