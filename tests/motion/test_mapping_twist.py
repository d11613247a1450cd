"""Twist bones hung along a limb (app/motion/mapping/along.py ``_twist_leaves``): a leaf on
the line of a sibling bone and short of its end is no branch of the body. Game rigs hang
them half-way along the upper arm, forearm, thigh and shin (Unreal's mannequin); nameless,
a rig with a one-chain hand took the twist leaf's branch for the arm's root. Likewise a
chain that starts so and runs on along that line (a sleeve bone on the forearm reaching past
the wrist): with the fingers cut, Mixamo's Granny took her sleeve's end for the hand."""

from __future__ import annotations

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.mapping.along import _twist_leaves
from app.motion.model import Motion, ParseLimits
from app.services.parser_pool import parse_scene
from bench.probe_mapping import PROBES, mapped_names, nameless, outcome, twist_leaves


def test_only_a_leaf_or_a_chain_along_a_longer_sibling_is_a_twist_leaf() -> None:
    # root, an arm going on to 9, a leaf along it, one off its line, one past its end, one
    # along it with a joint off the line below (6), a sleeve along it (7) whose end (8) lies
    # past the arm's end, a leaf joint along it (10) closed by an End Site off the line (11).
    parents = np.array([-1, 0, 0, 0, 0, 0, 5, 0, 7, 1, 0, 10])
    offsets = np.array(
        [
            [0, 0, 0],
            [1, 0, 0],
            [0.5, 0, 0],
            [0.5, 0.1, 0],
            [1.2, 0, 0],
            [0.4, 0, 0],
            [0, 1, 0],
            [0.6, 0, 0],
            [0.8, 0, 0],
            [0, -0.5, 0],
            [0.3, 0, 0],
            [0, 0.5, 0],
        ],
        dtype=float,
    )
    rest = offsets.copy()
    for j in (6, 8, 9, 11):
        rest[j] += rest[parents[j]]
    lengths = np.linalg.norm(offsets, axis=1)
    has_point = np.zeros(len(parents), dtype=bool)
    has_point[[0, 1, 5, 7, 10]] = True
    end_site = np.zeros(len(parents), dtype=bool)
    end_site[11] = True
    twist = _twist_leaves(parents, rest, lengths, has_point, end_site)
    # Joint 2 lies on the arm's line short of its end; 3 is 11 degrees off, 4 past the
    # arm's end (it is the longer one: the arm is not its twist), 5 has a joint off the line
    # below it; 7 starts on the line and its end 8 runs on along it past the arm's end; 10's
    # End Site is the BVH writer's, wherever it points.
    assert np.flatnonzero(twist).tolist() == [2, 7, 8, 10, 11]
    # The same joint 6 written as an End Site: a helper and its End Site.
    end_site[6] = True
    assert np.flatnonzero(_twist_leaves(parents, rest, lengths, has_point, end_site)).tolist() == [
        2,
        5,
        6,
        7,
        8,
        10,
        11,
    ]


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


@pytest.mark.parametrize("probe", ["short game rig", "SMPL-like + nameless"])
@pytest.mark.parametrize("name", ["granny_salsa.bvh", "granny_hiphop_noprefix.bvh"])
def test_sleeve_bones_along_the_forearm_are_no_hand(shared_data, name: str, probe: str) -> None:
    """Granny's ``Left_Sleeve`` hangs from the forearm on its line, 0.62 of the way to the
    wrist, its End Site past the wrist on that line (or, in the other export, pointing up
    the joint's own axis): with the fingers cut it passed for the hand."""
    motion = _first_frames(read_bvh(shared_data("wild-bvh", "mixamo", name).read_bytes()))
    expected, mirrored = mapped_names(motion)
    assert outcome(motion, expected, mirrored, PROBES[probe]) == "same"
