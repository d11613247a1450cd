"""app/motion/formats/leaf_bones.py: end bones longer than the whole figure (an exporter's
invented bone ends, as Blender writes them for a skeleton imported from glTF) end at their
joints; ends of a figure's size are kept."""

from __future__ import annotations

import dataclasses
import re

import numpy as np

from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.formats.leaf_bones import detached_leaves
from app.motion.kinematics import forward_kinematics
from app.motion.model import Skeleton
from app.motion.pipeline import analyse
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import build_glb

BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"
# Blender's invented ends on a re-exported Mixamo GLB (bench/exporter_variants.py): fingers
# 1.7 m, the head 22 m, on a figure 1.6 m tall; here every End Site 200 times its length.
STRETCH = 200.0


def _stretched_end_sites(text: str, factor: float) -> str:
    """The BVH ``text`` with every End Site's OFFSET multiplied by ``factor``."""

    def scaled(match: re.Match[str]) -> str:
        numbers = [float(v) * factor for v in match.group(2).split()]
        return match.group(1) + " ".join(f"{v:.5f}" for v in numbers)

    return re.sub(r"(End Site\s*\{\s*OFFSET\s+)([-\d.e ]+?)(?=\s*\})", scaled, text)


def _mapped(analysis) -> dict[str, str]:
    return {c: place["joint"] for c, place in analysis.joint_mapping["joints"].items()}


ENDS = {"head": "Head", "l_hand_tip": "LeftHandIndex1", "r_hand_tip": "RightHandIndex1"}
ENDS |= {"l_toe": "LeftToeBase", "r_toe": "RightToeBase"}


def _same_joints(stretched: dict[str, str], plain: dict[str, str]) -> None:
    """Every canonical joint on the same joint; an end point that was an End Site (now at
    its joint) on that joint, the same place."""
    for canonical, joint in plain.items():
        if canonical in ENDS and joint == f"{ENDS[canonical]}_end":
            assert stretched[canonical] in (joint, ENDS[canonical]), canonical
        else:
            assert stretched[canonical] == joint, canonical


def test_end_sites_longer_than_the_figure_end_at_their_joints() -> None:
    """On the code before, the stretched file was refused as a four-legged animal (the
    limb ends 200 times too far out); now it maps every canonical joint to the same joint
    as the file as written, and says which ends it left out."""
    text = BVH.read_text()
    plain = analyse(read_bvh(text.encode()))
    stretched = read_bvh(_stretched_end_sites(text, STRETCH).encode())
    assert "longer than the whole figure" in stretched.notes["warnings"][0]
    analysis = analyse(stretched)
    _same_joints(_mapped(analysis), _mapped(plain))
    assert analysis.joint_mapping["mirrored"] is False


def test_leaf_nodes_longer_than_the_figure_end_at_their_joints_in_gltf_too() -> None:
    """The same ends as leaf nodes of a GLB (Blender's FBX and glTF exporters write leaf
    bones): the same mapping as the file without them."""
    motion = read_bvh(BVH.read_bytes())
    skeleton = motion.skeleton
    offsets = skeleton.offsets.copy()
    offsets[skeleton.end_site] *= STRETCH
    stretched = dataclasses.replace(motion, skeleton=dataclasses.replace(skeleton, offsets=offsets))
    read, _, _ = read_gltf(build_glb(stretched))
    assert any("longer than the whole figure" in w for w in read.notes["warnings"])
    plain, _, _ = read_gltf(build_glb(motion))
    _same_joints(_mapped(analyse(read)), _mapped(analyse(plain)))


def test_ends_of_a_figures_size_are_kept() -> None:
    """A leaf as long as a limb or a sword (shorter than the figure) is as written."""
    motion = read_bvh(BVH.read_bytes())
    skeleton = motion.skeleton
    offsets = skeleton.offsets.copy()
    hand_end = int(np.flatnonzero(skeleton.end_site)[-1])
    _, at = forward_kinematics(motion.slice_frames(0, 1))
    figure = float(np.ptp(at[0][~skeleton.end_site], axis=0).max())
    offsets[hand_end] *= 0.6 * figure / np.linalg.norm(offsets[hand_end])
    assert detached_leaves(dataclasses.replace(skeleton, offsets=offsets)).size == 0
    offsets[hand_end] *= 4.0  # now longer than the figure
    assert detached_leaves(dataclasses.replace(skeleton, offsets=offsets)).tolist() == [hand_end]


def test_a_rig_of_too_few_inner_joints_is_left_as_it_is() -> None:
    """Limbs of one bone each (every limb a leaf from the trunk) leave no figure to measure
    a leaf against: nothing is done, whatever the lengths."""
    parents = np.array([-1, 0, 1, 1, 1, 0, 0])  # root, chest; head and arms; legs
    offsets = np.array(
        [
            [0, 1, 0],
            [0, 0.3, 0],
            [0, 0.3, 0],
            [0.5, 0, 0],
            [-0.5, 0, 0],
            [0.1, -1, 0],
            [-0.1, -1, 0],
        ],
        dtype=float,
    )
    names = tuple(f"j{j}" for j in range(len(parents)))
    skeleton = Skeleton(names, parents, offsets, np.zeros(len(parents), dtype=bool))
    assert detached_leaves(skeleton).size == 0


def test_the_warning_stays_beside_the_readers_other_warnings() -> None:
    """The BVH reader's own warnings (here decimal commas) are added to the end bones', not
    put in their place (they were, before this test: the end bones' warning was lost)."""
    text = _stretched_end_sites(BVH.read_text(), STRETCH)
    motion = read_bvh(text.replace(".", ",").encode())
    warnings = motion.notes["warnings"]
    assert any("decimal commas" in w for w in warnings), warnings
    assert any("longer than the whole figure" in w for w in warnings), warnings
