"""FBX (binary and ASCII, 6.x and 7.x; ufbx reads 5.0 too) -> :class:`Motion`.

Read with ufbx (its Python binding, pinned exactly: young, with object-lifetime bugs). **Call
these functions only in a worker process** (:mod:`app.services.parser_pool`): a crash in
the binding takes the process with it.

* Axes and units: ufbx converts the scene to right-handed Y-up metres from the file's own
  settings (``target_axes``, ``target_unit_meters``); ``length_unit`` says "metres".
* Skeleton: the limb nodes and the bones skin clusters name, the joinable nodes between
  them (nulls limbs hang from) — see :mod:`app.motion.formats.scene`; meshes, cameras,
  lights, markers and helper nulls that carry no bones are left out. A file with neither
  limb nodes nor skin clusters: the nodes its animation turns (a skeleton of nulls), unless
  what it animates is loose points, none below another (optical markers: refused saying so).
* Motion: every node's local transform baked by ufbx (pre/post rotation, pivots and offsets
  folded in, inherit modes compensated: ``inherit_mode_handling=COMPENSATE``) at the scene's
  frame rate, over the animation stack's time span.
* Several stacks: :func:`list_fbx_animations` lists them; :func:`read_fbx` reads the one
  named, else the longest.

Binding lifetime rules honoured here (see ``../shared/data/fbx-gltf/README.md``): the stack
list and each ``.anim`` are taken once and kept referenced until the end; parents come from
``children`` lists, never ``node.parent``.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, replace
from itertools import chain
from typing import Any

import numpy as np

from app.errors import LimitExceeded, ParseError
from app.motion.formats.scene import (
    MIN_MARKERS,
    OTHER_SKELETONS,
    NodeGraph,
    kept_parents,
    loose_points,
    markers_not_skeleton,
    motion_from_graph,
    other_skeletons,
    skeleton_nodes,
    unique_names,
    with_plain_nodes_below,
)
from app.motion.formats.scene_animation import (
    Animation,
    check_frame_budget,
    choice_warnings,
    no_skeleton,
    pick_animation,
    scene_notes,
)
from app.motion.formats.split_takes import TakeTracks, joined_take, moving_nodes
from app.motion.formats.split_takes import join as join_takes
from app.motion.formats.text import refuse_lfs_pointer
from app.motion.model import Motion, ParseLimits

DEFAULT_LIMITS = ParseLimits()
MAX_SCENE_NODES = 100_000
# Frames of each stack looked at for what it moves (spread over the stack), and the most
# stacks looked at (~0.7 ms each; Blender writes n objects' actions as about n x n stacks).
_LOOKED_AT = 256
_MAX_STACKS_LOOKED_AT = 2048
_TRANSFORMS = frozenset({"Lcl Translation", "Lcl Rotation", "Lcl Scaling"})


def _load(data: bytes, limits: ParseLimits) -> Any:
    refuse_lfs_pointer(data, "FBX file")
    import ufbx

    options: dict[str, Any] = {
        "ignore_geometry": True,
        "ignore_embedded": True,
        "load_external_files": False,
        "target_axes": ufbx.axes_right_handed_y_up,
        "target_unit_meters": 1.0,
        "space_conversion": ufbx.SpaceConversion.TRANSFORM_ROOT,
        "inherit_mode_handling": ufbx.InheritModeHandling.COMPENSATE,
        "file_format": ufbx.FileFormat.FBX,
    }
    if limits.max_depth is not None:
        options["node_depth_limit"] = limits.max_depth
    try:
        return ufbx.load_memory(data, **options)
    except ufbx.NodeDepthLimitError:
        raise LimitExceeded(
            f"the node hierarchy is nested deeper than the limit of {limits.max_depth}"
        ) from None
    except (ufbx.OutOfMemoryError, ufbx.MemoryLimitError, ufbx.AllocationLimitError):
        raise MemoryError from None
    except ufbx.UfbxError as error:
        raise ParseError(f"cannot read the FBX file: {_ufbx_message(error)}") from None


def _ufbx_message(error: Exception) -> str:
    text = str(error).strip().splitlines()
    return (text[0] if text else type(error).__name__)[:300]


def _check_key_times(scene: Any, held: list[Any]) -> None:
    """:class:`ParseError` naming the first animation curve whose keys start or end at a
    time that is no number: ufbx's bake samples from the first key to the last, and a NaN
    or infinite time there sends it on for as long as the parser's time limit allows. The
    curve wrappers go to ``held`` (kept with the scene: freeing one early crashes the
    binding)."""
    curves = list(scene.anim_curves)
    held.append(curves)
    for number, curve in enumerate(curves, start=1):
        first, last = float(curve.min_time), float(curve.max_time)
        if not (np.isfinite(first) and np.isfinite(last)):
            raise ParseError(
                f"animation curve {number} of {len(curves)} ({curve.name or 'unnamed'!r}) has a "
                f"key at a time that is not a number ({first!r} to {last!r} seconds)"
            )


class _Scene:
    """A loaded scene with its stacks and their ``Anim`` objects taken exactly once."""

    def __init__(self, data: bytes, limits: ParseLimits) -> None:
        self.scene = _load(data, limits)
        self.fps = float(self.scene.settings.frames_per_second) or 30.0
        if not np.isfinite(self.fps) or not 1.0 <= self.fps <= 1000.0:
            raise ParseError(f"the file's frame rate {self.fps!r} is not usable")
        self.held: list[Any] = []  # other wrappers taken from the scene, kept as long as it
        _check_key_times(self.scene, self.held)
        self.stacks = list(self.scene.anim_stacks)
        self.anims = [stack.anim for stack in self.stacks]
        names = unique_names(
            [stack.name for stack in self.stacks], blank="animation {i}", repeat="{name} ({n})"
        )
        self.spans = [(float(s.time_begin), float(s.time_end)) for s in self.stacks]
        self.joined: dict[str, list[Any]] = {}  # a take split over stacks: its stacks' anims
        self.animations = []
        for name, (begin, end), anim in zip(names, self.spans, self.anims, strict=True):
            span = end - begin if np.isfinite(end - begin) and end >= begin else 0.0
            frames = int(np.floor(span * self.fps + 0.5)) + 1
            moves = self._moves(anim)
            self.animations.append(Animation(name, frames, frames / self.fps, moves))

    def frame_times(self, index: int) -> np.ndarray:
        """``(F,)`` the times, in seconds, at which animation ``index`` is sampled."""
        begin = self.spans[index][0]
        return begin + np.arange(self.animations[index].frame_count) / self.fps

    def _moves(self, anim: Any) -> bool:
        """Whether a stack's layers animate any node's transform (an empty take does not)."""
        layers = list(anim.layers)
        props = [list(layer.anim_props) for layer in layers]
        self.held.append((layers, props))  # kept with the scene (see the module docstring)
        return any(prop.prop_name in _TRANSFORMS for each in props for prop in each)


def _animated_plain_nodes(
    loaded: _Scene, nodes: list[Any], joinable: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(N,)`` bools ``(plain, turned, moved)`` for a file with neither bones nor skin
    clusters: the joinable nodes that are nothing else (no mesh, camera or light: a Null,
    as Unity's FBX Exporter and some DCC and capture tools write a skeleton of them, or a
    marker), and the nodes an animation turns (a ``Lcl Rotation`` curve in any layer) or
    moves (``Lcl Translation``)."""
    index = {node.element_id: i for i, node in enumerate(nodes)}
    # By the attribute's type, a number: asking ``node.mesh`` hands out wrappers whose
    # freeing crashed the binding at the scene's end (a file of meshes and no bones).
    import ufbx

    # no attribute, a Null (ufbx reads an optical "Marker" model so), an effector
    nothing_else = {ufbx.ElementType.UNKNOWN, ufbx.ElementType.EMPTY, ufbx.ElementType.MARKER}
    plain = joinable & np.array([node.attrib_type in nothing_else for node in nodes], dtype=bool)
    turned = np.zeros(len(nodes), dtype=bool)
    moved = np.zeros(len(nodes), dtype=bool)
    # Every wrapper the binding hands out is kept referenced with the scene (freeing one
    # early crashes it, as for the stacks and their ``Anim`` objects).
    for anim in loaded.anims:
        layers = list(anim.layers)
        loaded.held.append(layers)
        for layer in layers:
            props = list(layer.anim_props)
            elements = [prop.element for prop in props]
            loaded.held.append((props, elements))
            for prop, element in zip(props, elements, strict=True):
                found = index.get(element.element_id)
                if found is None:
                    continue
                if prop.prop_name == "Lcl Rotation":
                    turned[found] = True
                elif prop.prop_name == "Lcl Translation":
                    moved[found] = True
    return plain, turned, moved


def list_fbx_animations(data: bytes, *, limits: ParseLimits = DEFAULT_LIMITS) -> list[Animation]:
    """The animation stacks of an FBX file, in file order."""
    return _Scene(data, limits).animations


def read_fbx(
    data: bytes,
    *,
    animation: str | None = None,
    limits: ParseLimits = DEFAULT_LIMITS,
    keep: list[Any] | None = None,
    still: bool = False,
) -> tuple[Motion, list[Animation], str]:
    """Read one animation of an FBX file (with ``still``, a file with a skeleton and no
    animation stack gives its rest pose as one frame: a rig).

    ``keep``: a list the loaded ufbx scene (with its stacks and ``Anim`` wrappers) is
    appended to, so the caller decides when, or whether, it is freed: freeing them can crash
    the binding (see the module docstring).

    Returns
    -------
    (motion, animations, chosen)
        The motion (``source_format="fbx"``, metres, Y up), every animation of the file and
        the name of the one read.

    Raises
    ------
    NoAnimation
        A rig: a skeleton without animation, or whose animation is zero-length.
    ParseError
        Not FBX, damaged, no skeleton, non-finite numbers, an unknown ``animation``.
    LimitExceeded
        Over ``limits`` (nodes, depth, joints, frames x nodes).
    """
    loaded = _Scene(data, limits)
    if keep is not None:
        keep.append(loaded)
    scene = loaded.scene
    nodes = list(scene.nodes)
    if len(nodes) > MAX_SCENE_NODES:
        raise LimitExceeded(
            f"the scene has {len(nodes)} nodes, more than the limit of {MAX_SCENE_NODES}"
        )
    # Parents from ``node.parent`` on nodes kept referenced in ``nodes`` (iterating
    # ``node.children`` crashes this binding), checked against the nodes' depths.
    node_ids = {node.typed_id: i for i, node in enumerate(nodes)}
    parents = np.full(len(nodes), -1, dtype=np.int64)
    depths = [node.node_depth for node in nodes]
    for i, node in enumerate(nodes):
        parent = node.parent
        if parent is None:
            continue
        index = node_ids.get(parent.typed_id)
        if index is None or depths[index] != depths[i] - 1:
            raise ParseError(f"the node hierarchy is inconsistent at node {node.name!r}")
        parents[i] = index
    is_bone = np.array([node.bone is not None for node in nodes], dtype=bool)
    clusters = list(scene.skin_clusters)
    bone_nodes = [cluster.bone_node for cluster in clusters]
    for bone in bone_nodes:
        if bone is not None and bone.typed_id in node_ids:
            is_bone[node_ids[bone.typed_id]] = True
    joinable = np.array(
        [
            not (node.is_root or node.is_scale_helper or node.is_geometry_transform_helper)
            for node in nodes
        ],
        dtype=bool,
    )
    what = "no bones or skin clusters"
    if not is_bone.any():
        # No bones: the nodes an animation turns are a skeleton of nulls (with the plain
        # nodes below them), unless what moves is loose points: optical markers.
        plain, turned, moved = _animated_plain_nodes(loaded, nodes, joinable)
        points = loose_points(plain & (turned | moved), parents)
        if points >= MIN_MARKERS:
            raise markers_not_skeleton(points)
        is_bone = with_plain_nodes_below(turned & plain, plain, parents)
        objects = int(np.sum((turned | moved) & ~plain))
        if objects:  # a prop or a lamp rig keyed object by object
            what += f"; its animation moves {objects} meshes, cameras or lights, not bones"
    if not is_bone.any():
        raise no_skeleton(loaded.animations, what)
    # Only the skeleton's nodes are sampled and counted (meshes, props, other trees are not).
    kept = skeleton_nodes(parents, is_bone, joinable)
    if not len(kept):
        raise no_skeleton(loaded.animations, "no bones or skin clusters")
    kept_nodes = [nodes[i] for i in kept]
    rest_t, rest_r, rest_s = _static(kept_nodes)
    kept_ids = {node.typed_id: i for i, node in enumerate(kept_nodes)}
    kept_depths = np.array([depths[i] for i in kept])
    _settle_takes(loaded, data, kept_ids, kept_depths, (rest_t, rest_r, rest_s), limits)
    if not loaded.animations and still:  # a rig: its rest pose as one frame
        loaded.animations = [Animation("", 1, 0.0)]
        info, warnings = loaded.animations[0], []
        translation, rotation, scale = rest_t[None], rest_r[None], rest_s[None]
    else:
        chosen = pick_animation(loaded.animations, animation, joints=int(is_bone.sum()))
        info = loaded.animations[chosen]
        warnings = choice_warnings(loaded.animations, chosen, animation)
        check_frame_budget(limits, info.frame_count, len(kept))
        times, rest = loaded.frame_times(chosen), (rest_t, rest_r, rest_s)
        parts = loaded.joined.get(info.name, [loaded.anims[chosen]])
        takes = [TakeTracks(*_baked(scene, p, kept_ids, times, loaded.fps, *rest)) for p in parts]
        take = takes[0] if len(takes) == 1 else join_takes(takes, _size(rest_t))
        translation, rotation, scale = take.translation, take.rotation, take.scale
    others_left = other_skeletons(parents, is_bone, kept)
    warnings = [*warnings, others_left] if others_left else warnings
    graph = NodeGraph(
        names=[node.name for node in kept_nodes],
        parents=kept_parents(parents, kept),
        is_bone=is_bone[kept],
        joinable=joinable[kept],
        rest_translation=rest_t,
        rest_rotation=rest_r,
        rest_scale=rest_s,
        translation=translation,
        rotation=rotation,
        scale=scale,
    )
    motion = motion_from_graph(
        graph,
        frame_time=1.0 / loaded.fps,
        source_format="fbx",
        length_unit="metres",
        limits=limits,
        notes=scene_notes(info, warnings),
    )
    if others_left:
        motion.notes[OTHER_SKELETONS] = others_left
    return motion, loaded.animations, info.name


@dataclass(frozen=True)
class _Settled:
    """What :func:`_look_at_takes` found in a file's stacks (by index in file order)."""

    still: frozenset[int]  # stacks that move no node of the skeleton
    joined: tuple[tuple[int, ...], ...]  # the stacks of each take written split over several


# The import reads a file once per animation, in one worker process: what its stacks move
# is looked at once per file (key: the file's digest and the frame budget), not per read.
_SETTLED: OrderedDict[tuple[bytes, int | None], _Settled] = OrderedDict()
_SETTLED_FILES = 16


def _settle_takes(
    loaded: _Scene,
    data: bytes,
    node_ids: dict[int, int],
    depths: np.ndarray,
    rest: tuple[np.ndarray, np.ndarray, np.ndarray],
    limits: ParseLimits,
) -> None:
    """With several stacks that animate something, settle ``loaded``'s animations from what
    each moves of the skeleton (:func:`_look_at_takes`, once per file ``data``):

    * a stack that moves no node of the skeleton (a prop's, a camera's, a control's) does
      not move: it is not read by default, and not a clip of its own;
    * stacks of one span that each move their own part of the skeleton are one take written
      split (:mod:`app.motion.formats.split_takes`): it is added, named after them joined by
      " + " and placed before the first of them, so it is what the file is read as by
      default; each stays readable by name."""
    candidates = [i for i, a in enumerate(loaded.animations) if a.moves and a.frame_count > 1]
    if not 2 <= len(candidates) <= _MAX_STACKS_LOOKED_AT:
        return
    key = (hashlib.blake2b(data, digest_size=16).digest(), limits.max_values)
    settled = _SETTLED.get(key)
    if settled is None:
        settled = _look_at_takes(loaded, candidates, node_ids, depths, rest, limits)
        _SETTLED[key] = settled
        while len(_SETTLED) > _SETTLED_FILES:
            _SETTLED.popitem(last=False)
    for i in settled.still:
        loaded.animations[i] = replace(loaded.animations[i], moves=False)
    for parts in sorted(settled.joined, key=lambda p: -p[0]):  # later ones first
        names = tuple(loaded.animations[i].name for i in parts)
        name = unique_names(
            [a.name for a in loaded.animations] + [" + ".join(names)],
            blank="animation {i}",
            repeat="{name} ({n})",
        )[-1]
        first, count = parts[0], loaded.animations[parts[0]].frame_count
        loaded.joined[name] = [loaded.anims[i] for i in parts]
        loaded.animations.insert(
            first, Animation(name, count, count / loaded.fps, True, parts=names)
        )
        loaded.spans.insert(first, loaded.spans[first])
        loaded.anims.insert(first, None)


def _look_at_takes(
    loaded: _Scene,
    candidates: list[int],
    node_ids: dict[int, int],
    depths: np.ndarray,
    rest: tuple[np.ndarray, np.ndarray, np.ndarray],
    limits: ParseLimits,
) -> _Settled:
    """Which of the ``candidates`` stacks move no node of the skeleton (the nodes of
    ``node_ids``; ``depths`` ``(N,)``: their depths in the scene), and which are one take
    written split. Looked at on frames spread over each stack; nothing found (the stacks
    as they are) when sampling every stack would cost more than reading the longest take
    may."""
    frames = sum(min(loaded.animations[i].frame_count, _LOOKED_AT) for i in candidates)
    if limits.frame_budget_problem(frames, 0, len(node_ids)):
        return _Settled(frozenset(), ())
    size = _size(rest[0])
    scene, fps = loaded.scene, loaded.fps
    looked: dict[int, TakeTracks] = {}
    still = set()
    for i in candidates:
        times = loaded.frame_times(i)
        times = times[np.unique(np.linspace(0, len(times) - 1, _LOOKED_AT).astype(int))]
        take = TakeTracks(*_baked(scene, loaded.anims[i], node_ids, times, fps, *rest))
        if moving_nodes(take, size).any():
            looked[i] = take
        else:
            still.add(i)
    spans: dict[tuple[int, int], list[int]] = {}  # (first frame, frames) -> stacks
    for i in looked:
        key = (round(loaded.spans[i][0] * fps), loaded.animations[i].frame_count)
        spans.setdefault(key, []).append(i)
    joined = []
    for (_, count), group in spans.items():
        parts = tuple(group[p] for p in joined_take([looked[i] for i in group], size, depths))
        if parts and not limits.frame_budget_problem(count * len(parts), 0, len(node_ids)):
            joined.append(parts)
    return _Settled(frozenset(still), tuple(joined))


def _size(rest_translation: np.ndarray) -> float:
    """A figure's size from its ``(N, 3)`` rest offsets: the longest (what "still" is
    measured against, :func:`app.motion.formats.split_takes.moving_nodes`)."""
    return float(np.linalg.norm(rest_translation, axis=1).max(initial=0.0))


def _static(nodes: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(N, 3)``, ``(N, 4)``, ``(N, 3)`` rest local translation, rotation, scale."""
    count = len(nodes)
    out = np.empty((count, 10))
    for i, node in enumerate(nodes):
        transform = node.local_transform
        t, r, s = transform.translation, transform.rotation, transform.scale
        out[i] = (t.x, t.y, t.z, r.x, r.y, r.z, r.w, s.x, s.y, s.z)
    return out[:, :3], out[:, 3:7], out[:, 7:]


def _baked(
    scene: Any,
    anim: Any,
    node_ids: dict[int, int],
    times: np.ndarray,
    fps: float,
    rest_t: np.ndarray,
    rest_r: np.ndarray,
    rest_s: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame local transforms ``(F, N, 3)``, ``(F, N, 4)``, ``(F, N, 3)`` of the ``N``
    nodes of ``node_ids`` (``typed_id`` -> index): those the stack animates from ufbx's bake
    (keys at every frame), the others at rest (a take that animates none of them is a pose
    held for its length: a still clip, as a BVH of repeated frames is)."""
    import ufbx

    frames = len(times)
    translation = np.broadcast_to(rest_t, (frames, *rest_t.shape)).copy()
    rotation = np.broadcast_to(rest_r, (frames, *rest_r.shape)).copy()
    scale = np.broadcast_to(rest_s, (frames, *rest_s.shape)).copy()
    try:
        bake = ufbx.bake_anim(scene, anim, resample_rate=fps, minimum_sample_rate=fps)
    except ufbx.UfbxError as error:
        raise ParseError(f"cannot sample the animation: {_ufbx_message(error)}") from None
    for baked in list(bake.nodes):
        index = node_ids.get(baked.typed_id)
        if index is None:
            continue
        for keys, out, width in (
            (baked.translation_keys, translation, 3),
            (baked.rotation_keys, rotation, 4),
            (baked.scale_keys, scale, 3),
        ):
            table = _key_table(keys, width)
            if table is None:
                continue
            if width == 4:
                out[:, index] = _sample_quaternions(table, times)
            else:
                out[:, index] = _sample(table, times)
    return translation, rotation, scale


def _key_table(keys: Any, width: int) -> np.ndarray | None:
    """``(K, 1 + width)`` rows ``(time, values...)`` of baked keys, or None when there are
    none. Keys are read once each and flattened straight into numpy: the binding builds a
    Python object per key and value, which is most of an FBX's reading time."""
    keys = list(keys)
    if not keys:
        return None
    values = [key.value for key in keys]
    table = np.empty((len(keys), 1 + width))
    table[:, 0] = np.fromiter((key.time for key in keys), float, count=len(keys))
    table[:, 1:] = np.fromiter(chain.from_iterable(values), float, count=width * len(keys)).reshape(
        -1, width
    )
    return table


def _sample(keys: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``(F, D)`` linear interpolation of ``(K, 1 + D)`` keys ``(time, values...)``."""
    if (
        len(keys) == len(times)
        and abs(keys[0, 0] - times[0]) < 1e-6
        and abs(keys[-1, 0] - times[-1]) < 1e-6
    ):
        return keys[:, 1:]  # baked at the frame rate: a key per frame
    return np.stack([np.interp(times, keys[:, 0], keys[:, c]) for c in range(1, keys.shape[1])], 1)


def _sample_quaternions(keys: np.ndarray, times: np.ndarray) -> np.ndarray:
    """``(F, 4)`` normalised linear interpolation of quaternion keys (signs made continuous)."""
    quats = keys[:, 1:]
    flips = np.ones(len(quats))
    flips[1:] = np.cumprod(np.where(np.sum(quats[1:] * quats[:-1], axis=1) < 0, -1.0, 1.0))
    quats = quats * flips[:, None]
    out = _sample(np.column_stack([keys[:, 0], quats]), times)
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(norm > 1e-12, norm, 1.0)
