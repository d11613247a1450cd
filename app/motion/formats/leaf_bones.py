"""Leaf bones longer than the figure they hang from: an exporter's invented bone ends.

A leaf joint (a BVH ``End Site``, a scene node with no child) only says where its parent's
bone ends. Some writers invent that end: Blender gives every bone a tail, and a skeleton
imported from glTF (joints are points there, bones have no ends) gets tails of a length
that comes from the armature's scale, not from the figure; its BVH exporter writes them as
End Sites and its FBX exporter as leaf bones (``add_leaf_bones``, the default). A Mixamo
character so re-exported ends its fingers 1.7 m and its head 22 m from their joints on a
figure 1.6 m tall, and the mapper, which takes limb ends among the leaves, reads a
creature with its limbs in the air.

No part of a body is longer than the whole body. A leaf whose bone is longer than the
extent of every joint that is not a leaf (the largest of the rest pose's sizes along the
three axes) is read as ending at its joint (its offset, and its per-frame translation if it
has one, set to zero), and the clip's warnings say which. A leaf of a figure's size or less
(a toe, a head top, a sword) is kept as written. Nothing is done where the joints that are
not leaves are too few to span a body (:data:`MIN_INNER`: limbs of one bone, a lamp,
markers on one joint).

Shapes: ``local_translations`` ``(F, J, 3)``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from app.motion.model import Skeleton
from app.motion.skeleton_map import rest_pose

_SHOWN = 4  # leaf names a warning lists
# The joints that are not leaves span a body only when they hold its limbs: at least two
# joints of each of the four (hip and knee, shoulder and elbow). Fewer (limbs of one bone,
# each a leaf; a lamp; markers on a root) leave no figure to measure a leaf against.
MIN_INNER = 8


def detached_leaves(skeleton: Skeleton) -> np.ndarray:
    """Indices of the leaf joints whose bone is longer than the figure (see above)."""
    parents = skeleton.parents
    has_child = np.zeros(skeleton.joint_count, dtype=bool)
    has_child[parents[parents >= 0]] = True
    leaves = np.flatnonzero(~has_child & (parents >= 0))
    inner = np.flatnonzero(has_child)
    if leaves.size == 0 or inner.size < MIN_INNER:
        return np.zeros(0, dtype=np.int64)
    extent = float(np.ptp(rest_pose(skeleton)[inner], axis=0).max())
    if not extent > 0:
        return np.zeros(0, dtype=np.int64)
    lengths = np.linalg.norm(skeleton.offsets[leaves], axis=1)
    return leaves[lengths > extent]


def without_detached_leaves(
    skeleton: Skeleton, local_translations: np.ndarray | None
) -> tuple[Skeleton, np.ndarray | None, str | None]:
    """``skeleton`` and ``local_translations`` with the detached leaves ending at their
    joints (copies where changed), and the warning that says so (None: none)."""
    found = detached_leaves(skeleton)
    if found.size == 0:
        return skeleton, local_translations, None
    offsets = skeleton.offsets.copy()
    offsets[found] = 0.0
    if local_translations is not None:
        local_translations = local_translations.copy()
        local_translations[:, found] = 0.0
    shown = ", ".join(repr(skeleton.names[j]) for j in found[:_SHOWN])
    more = f" and {found.size - _SHOWN} more" if found.size > _SHOWN else ""
    warning = (
        f"{found.size} end bone(s) longer than the whole figure ({shown}{more}) read as "
        "ending at their joint: an exporter's invented bone ends, no part of the body"
    )
    return dataclasses.replace(skeleton, offsets=offsets), local_translations, warning
