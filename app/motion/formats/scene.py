"""From a node graph with sampled transforms (FBX, glTF) to a :class:`Motion`.

Both scene formats describe a tree of nodes, each with a local translation, rotation and
scale, of which some are the bones of a skeleton. The readers sample every node's local
transform per frame; this module composes them into world transforms (``world = parent @
local``), picks the skeleton's joints and re-expresses the world transforms in the
:class:`Motion` model (a rotation per joint, rest offsets, the root's translation) with BVH's
convention: every joint's frame is the world's in the rest pose, so the offsets summed down
the tree are the file's rest pose.

Working from world transforms makes everything between the bones not matter: helper nodes,
an ``Armature`` or a ``Reference`` null above the root (with its scale or axis change), and
scale on a bone: a joint's rotation is the orthonormal part of its world matrix, and where
a child does not stay at a constant offset in its parent's rotated frame (animated
translation, scale), the per-frame offsets go into ``Motion.local_translations``, so forward
kinematics gives back the file's joint positions exactly.

Quaternions are ``(x, y, z, w)`` as in both formats. Which animation of a file is read, and
the errors of a file without skeleton or motion: :mod:`app.motion.formats.scene_animation`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.errors import LimitExceeded, ParseError
from app.motion.formats.leaf_bones import without_detached_leaves
from app.motion.model import Motion, ParseLimits, Skeleton

# A child whose offset in its parent's frame moves by more than this fraction of the body's
# size over the clip is given per-frame offsets (``local_translations``).
OFFSET_TOLERANCE = 1e-6
# Node transforms composed per chunk of frames in :func:`motion_from_graph`.
SCENE_TRANSFORMS_PER_CHUNK = 65_536


@dataclass(frozen=True, eq=False)
class NodeGraph:
    """Every node of a scene that the skeleton needs, with sampled local transforms.

    Attributes
    ----------
    names:
        ``(N,)`` node names (as in the file; may repeat or be empty).
    parents:
        ``(N,)`` int64 index of each node's parent, ``-1`` at a top-level node; any order.
    is_bone:
        ``(N,)`` bool, the nodes the file declares as bones (FBX limb nodes and skin
        clusters' bones, glTF skin joints, VRM humanoid bones).
    joinable:
        ``(N,)`` bool, nodes that may become a joint when they lie between bones (False for
        a reader's own helper nodes).
    rest_translation, rest_rotation, rest_scale:
        ``(N, 3)``, ``(N, 4)`` and ``(N, 3)`` local transform in the rest (default) pose.
    translation, rotation, scale:
        ``(F, N, 3)``, ``(F, N, 4)``, ``(F, N, 3)`` local transform per frame.
    """

    names: Sequence[str]
    parents: np.ndarray
    is_bone: np.ndarray
    joinable: np.ndarray
    rest_translation: np.ndarray
    rest_rotation: np.ndarray
    rest_scale: np.ndarray
    translation: np.ndarray
    rotation: np.ndarray
    scale: np.ndarray


def quaternion_matrices(quaternions: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotation matrices of ``(..., 4)`` ``(x, y, z, w)`` quaternions
    (normalised first; a zero quaternion gives the identity)."""
    q = np.asarray(quaternions, dtype=np.float64)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(norm > 1e-12, q / np.where(norm > 1e-12, norm, 1.0), [0.0, 0.0, 0.0, 1.0])
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def topological(parents: np.ndarray) -> list[int]:
    """Node indices with every parent before its children (a cycle raises ParseError)."""
    count = len(parents)
    children: list[list[int]] = [[] for _ in range(count)]
    roots = []
    for node, parent in enumerate(parents.tolist()):
        if parent < 0:
            roots.append(node)
        else:
            children[parent].append(node)
    order: list[int] = []
    stack = roots[::-1]
    while stack:
        node = stack.pop()
        order.append(node)
        stack.extend(children[node][::-1])
    if len(order) != count:
        raise ParseError("the node hierarchy has a cycle")
    return order


def compose_world(
    parents: np.ndarray, translation: np.ndarray, rotation: np.ndarray, scale: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World transforms of every node.

    Parameters
    ----------
    parents:
        ``(N,)`` parent index per node, ``-1`` at top-level nodes.
    translation, rotation, scale:
        ``(..., N, 3)``, ``(..., N, 4)``, ``(..., N, 3)`` local transforms.

    Returns
    -------
    linear:
        ``(..., N, 3, 3)`` world linear part (rotation times scale).
    position:
        ``(..., N, 3)`` world position.
    """
    local = quaternion_matrices(rotation) * scale[..., None, :]
    linear = np.empty_like(local)
    position = np.empty_like(translation, dtype=np.float64)
    # Level by level from the top: every node of a level in one batched product.
    depth = np.zeros(len(parents), dtype=np.int64)
    for node in topological(parents):
        if parents[node] >= 0:
            depth[node] = depth[parents[node]] + 1
    for level in range(int(depth.max(initial=0)) + 1):
        nodes = np.flatnonzero(depth == level)
        if level == 0:
            linear[..., nodes, :, :] = local[..., nodes, :, :]
            position[..., nodes, :] = translation[..., nodes, :]
            continue
        up = parents[nodes]
        parent_linear = linear[..., up, :, :]
        linear[..., nodes, :, :] = parent_linear @ local[..., nodes, :, :]
        position[..., nodes, :] = (
            position[..., up, :] + (parent_linear @ translation[..., nodes, :, None])[..., 0]
        )
    return linear, position


def orthonormal(linear: np.ndarray) -> np.ndarray:
    """The rotation part of ``(..., 3, 3)`` matrices (Gram-Schmidt on the first two columns;
    degenerate ones — a bone scaled to zero — become the identity)."""
    x = linear[..., :, 0]
    y = linear[..., :, 1]
    x_norm = np.linalg.norm(x, axis=-1, keepdims=True)
    x = x / np.where(x_norm > 1e-12, x_norm, 1.0)
    y = y - np.sum(x * y, axis=-1, keepdims=True) * x
    y_norm = np.linalg.norm(y, axis=-1, keepdims=True)
    y = y / np.where(y_norm > 1e-12, y_norm, 1.0)
    z = np.cross(x, y)
    out = np.stack([x, y, z], axis=-1)
    bad = (x_norm[..., 0] <= 1e-12) | (y_norm[..., 0] <= 1e-12)
    if np.any(bad):
        out[bad] = np.eye(3)
    return out


def select_joints(parents: np.ndarray, is_bone: np.ndarray, joinable: np.ndarray) -> list[int]:
    """The nodes that make the skeleton, depth first from its root.

    The bones, the joinable nodes between two bones (a null a limb hangs from) and, when the
    bones form several trees, their lowest common ancestor as the root; when that would be
    the scene itself (unrelated trees), the tree with the most bones.
    """
    count = len(parents)
    bones = set(np.flatnonzero(is_bone).tolist())
    if not bones:
        return []

    def chain(node: int) -> list[int]:  # node, its parent, ..., its top-level ancestor
        out: list[int] = []
        while node >= 0 and len(out) <= count:
            out.append(node)
            node = int(parents[node])
        return out

    chains = {bone: chain(bone) for bone in bones}
    # Nodes between bones: ancestors of a bone below another bone (joinable ones only).
    selected = set(bones)
    for bone, path in chains.items():
        above = path[1:]
        top = next((i for i, node in enumerate(above) if node in bones), None)
        if top is not None:
            selected.update(node for node in above[:top] if joinable[node])
        del bone
    tops = [b for b in bones if not any(n in bones for n in chains[b][1:])]
    if len(tops) > 1:
        common = set(chains[tops[0]])
        for top in tops[1:]:
            common &= set(chains[top])
        lowest = next((n for n in chains[tops[0]] if n in common), None)
        if lowest is not None and joinable[lowest]:
            for top in tops:
                for node in chains[top][1:]:
                    if node == lowest:
                        break
                    if joinable[node]:
                        selected.add(node)
            selected.add(lowest)
        else:  # unrelated trees: keep the biggest
            sizes = {t: sum(1 for b in bones if t in chains[b]) for t in tops}
            best = max(tops, key=lambda t: (sizes[t], -t))
            selected = {n for n in selected if best in chain(n)}
    children: dict[int, list[int]] = {}
    for node in range(count):
        children.setdefault(int(parents[node]), []).append(node)
    roots = [n for n in selected if not any(a in selected for a in chain(n)[1:])]
    order: list[int] = []

    def visit(node: int) -> None:  # depth first over selected nodes, skipping the others
        stack = [node]
        while stack:
            current = stack.pop()
            if current in selected:
                order.append(current)
            stack.extend(reversed(children.get(current, [])))

    for root in sorted(roots):
        visit(root)
    return order


def with_plain_nodes_below(
    animated: np.ndarray, plain: np.ndarray, parents: np.ndarray
) -> np.ndarray:
    """``(N,)`` bool: the ``animated`` ``(N,)`` nodes and the ``plain`` ``(N,)`` ones (no mesh,
    camera, light or skin) below any of them — a skeleton read from what an animation moves,
    with its end bones, when a file names no bones (glTF without a skin, FBX of Null nodes).
    ``parents`` ``(N,)``; a cycle is walked at most ``N`` steps (the caller refuses it)."""
    chosen = animated.copy()
    for i in np.flatnonzero(plain & ~animated):
        j, steps = int(parents[i]), 0
        while j >= 0 and steps <= len(parents):
            if animated[j]:
                chosen[i] = True
                break
            j, steps = int(parents[j]), steps + 1
    return chosen


#: Loose animated points (no skeleton) from which a file is called a marker cloud.
MIN_MARKERS = 3


def loose_points(animated: np.ndarray, parents: np.ndarray) -> int:
    """How many ``animated`` ``(N,)`` nodes there are when none of them hangs below another
    (``parents`` ``(N,)``), else 0. A skeleton's animated nodes form chains (a forearm turns
    below its upper arm); optical markers are loose points, each moved on its own. Nodes
    not reached from a top-level one (a cycle) are not looked at."""
    return 0 if (animated & (carriers(parents, animated) >= 0)).any() else int(animated.sum())


def carriers(parents: np.ndarray, animated: np.ndarray) -> np.ndarray:
    """``(N,)`` for each node below an ``animated`` node the nearest such ancestor, else -1
    (one walk from the top nodes down; nodes in a cycle are not reached)."""
    out = np.full(len(parents), -1, dtype=np.int64)
    children: list[list[int]] = [[] for _ in parents]
    stack = []
    for i, parent in enumerate(parents.tolist()):
        if 0 <= parent < len(parents):
            children[parent].append(i)
        else:
            stack.append(i)
    while stack:
        node = stack.pop()
        carrier = node if animated[node] else int(out[node])
        for child in children[node]:
            out[child] = carrier
            stack.append(child)
    return out


def markers_not_skeleton(count: int) -> ParseError:
    """The error for a file whose only motion is ``count`` loose points (no skeleton)."""
    return ParseError(
        f"the file holds {count} moving points (motion-capture markers) and no skeleton: no "
        "bones, skin or animated nodes that hang from one another. Markers are not a "
        "skeleton; solve them onto one in the capture software and upload that"
    )


def skeleton_nodes(parents: np.ndarray, is_bone: np.ndarray, joinable: np.ndarray) -> np.ndarray:
    """``(K,)`` sorted indices of the nodes the skeleton needs: its joints
    (:func:`select_joints`) and all their ancestors. The readers sample these nodes only
    (meshes, cameras, props and bones of other trees are never sampled or counted), and a
    graph of them selects the same joints in the same order."""
    needed: set[int] = set()
    for joint in select_joints(parents, is_bone, joinable):
        node = joint
        while node >= 0 and node not in needed:
            needed.add(node)
            node = int(parents[node])
    return np.array(sorted(needed), dtype=np.int64)


# ``Motion.notes`` key of :func:`other_skeletons`' sentence (also one of the warnings): a
# refusal of the skeleton read says it too (app/motion/body.py), since the part the body
# lacks may be the one left out.
OTHER_SKELETONS = "other_skeletons"


def other_skeletons(parents: np.ndarray, is_bone: np.ndarray, kept: np.ndarray) -> str | None:
    """A warning when bones of ``(N,)`` ``is_bone`` lie outside the skeleton's ``kept``
    nodes (:func:`skeleton_nodes`): the file holds unrelated skeletons (two characters, a
    prop's rig) and only the one with the most bones is read — said, so that a user who
    wanted the other knows it was not."""
    left = np.flatnonzero(is_bone)
    left = left[~np.isin(left, kept)]
    if not len(left):
        return None
    tops = int(np.count_nonzero(carriers(parents, is_bone)[left] < 0))  # no bone above them
    return (
        f"the file holds {tops} other skeleton{'s' if tops > 1 else ''} ({len(left)} bones "
        "not joined to this one); the one with the most bones was read"
    )


def kept_parents(parents: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``(K,)`` parents of the nodes ``keep`` (closed under ancestors), as indices into it."""
    remap = np.full(len(parents), -1, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    return np.where(parents[keep] >= 0, remap[np.maximum(parents[keep], 0)], -1)


def unique_names(
    names: Sequence[str], *, blank: str = "joint{i}", repeat: str = "{name}_{n}"
) -> tuple[str, ...]:
    """Names made unique (``Bone``, ``Bone_2``...; the ``repeat`` pattern), blank ones named
    by the ``blank`` pattern (``joint<i>``, ``i`` from 0)."""
    seen: set[str] = set()
    out = []
    for i, raw in enumerate(names):
        name = raw.strip() or blank.format(i=i)
        candidate, n = name, 1
        while candidate in seen:
            n += 1
            candidate = repeat.format(name=name, n=n)
        seen.add(candidate)
        out.append(candidate)
    return tuple(out)


def check_finite(array: np.ndarray, what: str, names: Sequence[str], axis: int) -> None:
    """ParseError naming the first node whose numbers in ``array`` are not finite."""
    finite = np.isfinite(array)
    if finite.all():
        return
    bad = np.argwhere(~finite)[0]
    node = int(bad[axis])
    raise ParseError(
        f"non-finite number (inf or NaN) in the {what} of node {names[node]!r}; the file is damaged"
    )


def motion_from_graph(
    graph: NodeGraph,
    *,
    frame_time: float,
    source_format: str,
    length_unit: str,
    limits: ParseLimits,
    notes: dict[str, object] | None = None,
) -> Motion:
    """The :class:`Motion` of ``graph``'s skeleton (see the module docstring).

    Raises
    ------
    ParseError
        No bones, non-finite transforms, a cycle.
    LimitExceeded
        More joints than ``limits.max_joints``.
    """
    names = list(graph.names)
    for array, what in (
        (graph.rest_translation, "rest translation"),
        (graph.rest_rotation, "rest rotation"),
        (graph.rest_scale, "rest scale"),
    ):
        check_finite(array, what, names, axis=0)
    for array, what in (
        (graph.translation, "animated translation"),
        (graph.rotation, "animated rotation"),
        (graph.scale, "animated scale"),
    ):
        check_finite(array, what, names, axis=1)
    joints = select_joints(graph.parents, graph.is_bone, graph.joinable)
    if not joints:
        raise ParseError("the file has no skeleton (no bones or skin joints)")
    if limits.max_joints is not None and len(joints) > limits.max_joints:
        raise LimitExceeded(
            f"the skeleton has {len(joints)} joints, more than the limit of {limits.max_joints}"
        )
    # Only the nodes on the joints' paths to the top need composing.
    needed: set[int] = set()
    for joint in joints:
        node = joint
        while node >= 0 and node not in needed:
            needed.add(node)
            node = int(graph.parents[node])
    keep = np.array(sorted(needed))
    parents = kept_parents(graph.parents, keep)
    rest_linear, rest_position = compose_world(
        parents,
        graph.rest_translation[keep],
        graph.rest_rotation[keep],
        graph.rest_scale[keep],
    )
    remap = np.full(len(names), -1)
    remap[keep] = np.arange(len(keep))
    columns = remap[np.array(joints)]
    joint_index = {node: j for j, node in enumerate(joints)}
    joint_parents = np.full(len(joints), -1, dtype=np.int64)
    for j, node in enumerate(joints):
        parent = int(graph.parents[node])
        while parent >= 0 and parent not in joint_index:
            parent = int(graph.parents[parent])
        joint_parents[j] = joint_index[parent] if parent >= 0 else -1
    rest_world = orthonormal(rest_linear[columns])  # (J, 3, 3)
    rest_at = rest_position[columns]  # (J, 3)

    count = len(joints)
    root = joint_parents < 0
    up = np.where(root, 0, joint_parents)
    # BVH's convention: every joint's frame is the world's in the rest pose, so the offsets
    # summed down the tree are the rest pose as the file shows it (a standing figure where
    # the file has one, whatever joint orientations its bones carry) and a joint's rotation
    # is how far it turned from there.
    offsets = rest_at - rest_at[up]
    offsets[root] = 0.0
    frames = graph.translation.shape[0]
    local_rotations = np.empty((frames, count, 3, 3))
    per_frame = np.empty((frames, count, 3))
    root_translation = np.empty((frames, 3))
    joint_names = [names[n] for n in joints]
    # A chunk of frames at a time: every step is per frame, and the world transforms of the
    # kept nodes and their temporaries never exist for the whole clip at once.
    step = max(1, SCENE_TRANSFORMS_PER_CHUNK // max(1, len(keep)))
    for start in range(0, frames, step):
        chunk = slice(start, min(start + step, frames))
        linear, position = compose_world(
            parents,
            graph.translation[chunk][:, keep],
            graph.rotation[chunk][:, keep],
            graph.scale[chunk][:, keep],
        )
        at = position[:, columns]  # (f, J, 3)
        check_finite(at, "world position", joint_names, axis=1)
        world = orthonormal(linear[:, columns]) @ np.swapaxes(rest_world, -1, -2)[None]
        parent_t = np.swapaxes(world[:, up], -1, -2)  # (f, J, 3, 3)
        local = parent_t @ world
        local[:, root] = world[:, root]
        local_rotations[chunk] = local
        per_frame[chunk] = (parent_t @ (at - at[:, up])[..., None])[..., 0]
        root_translation[chunk] = at[:, 0]
        limits.check_time()
    per_frame[:, root] = 0.0
    size = float(np.ptp(rest_at, axis=0).max()) if count > 1 else 0.0
    moved = float(np.abs(per_frame[:, 1:] - offsets[1:]).max()) if count > 1 else 0.0
    local_translations = per_frame if moved > OFFSET_TOLERANCE * max(size, 1e-9) else None
    skeleton = Skeleton(
        names=unique_names([names[n] for n in joints]),
        parents=joint_parents,
        offsets=offsets,
        end_site=np.zeros(count, dtype=bool),
    )
    skeleton, local_translations, leaf_warning = without_detached_leaves(
        skeleton, local_translations
    )
    notes = dict(notes or {})
    if leaf_warning:
        said = notes.get("warnings")
        notes["warnings"] = [*(said if isinstance(said, list | tuple) else ()), leaf_warning]
    return Motion(
        skeleton=skeleton,
        frame_time=frame_time,
        root_translation=root_translation,
        local_rotations=local_rotations,
        local_translations=local_translations,
        source_format=source_format,
        length_unit=length_unit,
        notes=notes,
    )
