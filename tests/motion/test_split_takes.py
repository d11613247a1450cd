"""Which animations of one span are one take written split (app/motion/formats/split_takes.py).

The rule on tracks built here (the Blender-written file is tests/motion/test_fbx.py's):
nodes 0 (a root null), 1 (an armature object below it), 2-5 (bones)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.motion.formats.split_takes import TakeTracks, join, joined_take, moving_nodes

FRAMES, NODES = 60, 6
DEPTHS = np.arange(NODES)
SIZE = 1.0


def _still() -> TakeTracks:
    rotation = np.tile([0.0, 0.0, 0.0, 1.0], (FRAMES, NODES, 1))
    translation = np.tile(np.linspace(0.1, 0.6, NODES)[:, None] * [0, 1, 0], (FRAMES, 1, 1))
    return TakeTracks(translation, rotation, np.ones((FRAMES, NODES, 3)))


def _moving(nodes: list[int], seed: int) -> TakeTracks:
    """A take moving ``nodes`` (turns and travel), the others at rest."""
    take, rng = _still(), np.random.default_rng(seed)
    for node in nodes:
        turns = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (FRAMES, 3)), axis=0))
        take.rotation[:, node] = turns.as_quat()
        take.translation[:, node] += np.cumsum(rng.normal(0, 0.01, (FRAMES, 3)), axis=0)
    return take


def _written_on(take: TakeTracks, source: int, target: int) -> TakeTracks:
    """``take``'s motion of node ``source`` written on node ``target`` under a fixed
    transform (an action written on a second object, whose parent-inverse is not identity)."""
    out = _still()
    fixed = Rotation.from_euler("xyz", [0.3, -0.2, 0.9])
    turns = fixed * Rotation.from_quat(take.rotation[:, source])
    out.rotation[:, target] = turns.as_quat()
    shift = np.array([0.5, 0.1, -0.2])
    out.translation[:, target] = shift + fixed.apply(take.translation[:, source])
    return out


def test_parts_that_each_move_their_own_nodes_are_one_take() -> None:
    travel, body = _moving([0], 1), _moving([2, 3, 4, 5], 2)
    assert joined_take([travel, _still(), body], SIZE, DEPTHS) == [0, 2]
    take = join([travel, body], SIZE)
    assert np.array_equal(take.rotation[:, 0], travel.rotation[:, 0])
    assert np.array_equal(take.rotation[:, 2:], body.rotation[:, 2:])


def test_an_action_repeated_on_a_node_below_is_left_out_and_the_top_one_kept() -> None:
    travel, body = _moving([0], 1), _moving([2, 3, 4, 5], 2)
    repeated = _written_on(travel, 0, 1)
    assert joined_take([repeated, body, travel], SIZE, DEPTHS) == [1, 2]


def test_two_takes_that_move_the_same_nodes_are_not_joined() -> None:
    walk, run = _moving([0, 2, 3], 3), _moving([0, 2, 3], 4)
    assert joined_take([walk, run], SIZE, DEPTHS) == []
    # a third, disjoint part does not make the two one take
    assert joined_take([walk, run, _moving([4, 5], 5)], SIZE, DEPTHS) == []


def test_one_moving_take_beside_still_ones_is_no_split_take() -> None:
    assert joined_take([_moving([2, 3], 6), _still(), _still()], SIZE, DEPTHS) == []


def test_baking_noise_is_still_and_a_small_real_turn_is_not() -> None:
    take = _still()
    take.rotation[:, 2] = Rotation.from_rotvec(
        np.random.default_rng(7).normal(0, 1e-5, (FRAMES, 3))
    ).as_quat()
    take.translation[:, 3] += 1e-6
    assert not moving_nodes(take, SIZE).any()
    take.rotation[-1, 4] = Rotation.from_euler("x", 1.0, degrees=True).as_quat()
    assert np.flatnonzero(moving_nodes(take, SIZE)).tolist() == [4]
