"""glTF 2.0 (``.glb``, ``.gltf`` with embedded buffers) and VRM animation (``.vrma``) ->
:class:`Motion`.

Read with the standard library (GLB chunks, JSON) and numpy (buffers, accessors,
sampling): pygltflib's dataclass decoding took 3-7 s on files with a few dozen animations,
more than parsing everything else. Run in a
parser worker (:mod:`app.services.parser_pool`) like the FBX reader: the files are untrusted
binary input.

* Buffers: the GLB binary chunk or ``data:`` URIs only. A ``uri`` naming anything else (a
  file beside it, ``../``, an absolute path, ``http://``) is refused: nothing is ever read
  from the file system or the network; upload a ``.glb``.
* Skeleton: the joints of every skin, or for a ``.vrma`` the nodes of its
  ``VRMC_vrm_animation`` ``humanBones`` map (named after the human bone, e.g. ``leftUpperArm``),
  or, in a file with neither (an animation exported without its mesh), the nodes its channels
  turn or move and the plain nodes below them; plus the nodes between them
  (:mod:`app.motion.formats.scene`).
* Channels: a node's ``translation``, ``rotation`` or ``scale``, named by ``target.node`` and
  ``target.path`` or by a ``KHR_animation_pointer`` JSON pointer (``/nodes/3/rotation``);
  pointers to anything else (materials, cameras, lights, extension properties) are not a
  skeleton's and are left out with a warning, morph weights silently.
* Motion: channels sampled with their interpolation (``LINEAR`` — quaternions slerped —,
  ``STEP``, ``CUBICSPLINE``) at the keyframe rate when the keys are evenly spaced (raised to
  a whole multiple of it of at least 24 fps, so every key is still a frame), else 30 fps.
* Units: glTF says metres, Y up; files do not always keep to it (the body-height
  normalisation downstream makes the scale not matter). ``length_unit`` says "metres (glTF)".
"""

from __future__ import annotations

import re
from dataclasses import replace
from typing import Any

import numpy as np

from app.errors import LimitExceeded, ParseError
from app.motion.formats.gltf_data import accessor_values, buffers_of, load_document
from app.motion.formats.gltf_schema import check_node_transform, shown
from app.motion.formats.scene import (
    MIN_MARKERS,
    OTHER_SKELETONS,
    NodeGraph,
    carriers,
    kept_parents,
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
from app.motion.formats.text import show
from app.motion.model import Motion, ParseLimits

DEFAULT_LIMITS = ParseLimits()
MAX_NODES = 100_000
DEFAULT_FPS = 30.0
MIN_FPS = 24.0
MAX_KEY_FPS = 240.0

_PATHS = {"translation": 3, "rotation": 4, "scale": 3}
_NOT_JOINT = ("mesh", "camera", "skin")  # node fields that make a node something else
POINTER = "KHR_animation_pointer"
# A JSON pointer (RFC 6901) to a node's transform or weights: an array index is "0" or has no
# leading zero; these property names need no ~0/~1 escapes, so a pointer with one is another
# property. Read only when short: a longer pointer never names a node property.
_NODE_POINTER_RE = re.compile(r"/nodes/(0|[1-9][0-9]{0,8})/(translation|rotation|scale|weights)")
_MAX_NODE_POINTER = 40


def _node_transform(node: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A node's rest local translation, rotation ``(x, y, z, w)`` and scale."""
    matrix = getattr(node, "matrix", None)
    if matrix is not None:
        m = np.asarray(matrix, dtype=np.float64).reshape(4, 4).T  # column-major
        translation = m[:3, 3].copy()
        linear = m[:3, :3]
        scale = np.linalg.norm(linear, axis=0)
        rotation = linear / np.where(scale > 1e-12, scale, 1.0)
        if np.linalg.det(rotation) < 0:
            scale[0], rotation[:, 0] = -scale[0], -rotation[:, 0]
        return translation, _matrix_quaternion(rotation), scale
    t = node.translation if node.translation is not None else [0.0, 0.0, 0.0]
    r = node.rotation if node.rotation is not None else [0.0, 0.0, 0.0, 1.0]
    s = node.scale if node.scale is not None else [1.0, 1.0, 1.0]
    # (3, 4 and 3 numbers: gltf_schema.check_node_transform, asked before)
    return np.asarray(t, np.float64), np.asarray(r, np.float64), np.asarray(s, np.float64)


def _matrix_quaternion(m: np.ndarray) -> np.ndarray:
    """``(x, y, z, w)`` of a ``(3, 3)`` rotation matrix."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 1e-12))
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 1e-12))
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 1e-12))
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    return np.asarray(q)


def _human_bones(document: Any) -> dict[int, str]:
    """VRM animation: node index -> human bone name (``hips``, ``leftUpperArm``...)."""
    extensions = document.extensions or {}
    vrma = extensions.get("VRMC_vrm_animation") if isinstance(extensions, dict) else None
    if not isinstance(vrma, dict):
        return {}
    humanoid = vrma.get("humanoid")
    bones = humanoid.get("humanBones") if isinstance(humanoid, dict) else None
    if not isinstance(bones, dict):
        return {}
    out = {}
    for name, entry in bones.items():
        node = entry.get("node") if isinstance(entry, dict) else None
        if isinstance(node, int) and isinstance(name, str):
            out[node] = name
    return out


def channel_target(channel: Any) -> tuple[Any, Any, str | None]:
    """``(node, path, other)`` a channel animates: its ``target.node`` and ``target.path``,
    or for a ``KHR_animation_pointer`` channel (path ``"pointer"``, no node) the node index
    and property its JSON pointer names. ``other`` is the pointer when it names anything
    else (a material's colour, a camera's field of view...), with node and path ``None``."""
    target = getattr(channel, "target", None)
    path = getattr(target, "path", None)
    if path != "pointer":
        return getattr(target, "node", None), path, None
    extensions = getattr(target, "extensions", None)
    entry = extensions.get(POINTER) if isinstance(extensions, dict) else None
    pointer = entry.get("pointer") if isinstance(entry, dict) else None
    if not isinstance(pointer, str):
        return None, None, "(a pointer channel without its pointer)"
    match = None
    if len(pointer) <= _MAX_NODE_POINTER:
        match = _NODE_POINTER_RE.fullmatch(pointer)
    if match is None:
        return None, None, pointer
    return int(match[1]), match[2], None


def _pointer_warning(others: list[str]) -> list[str]:
    """The warning for an animation's pointer channels that animate no node transform."""
    if not others:
        return []
    return [
        f"{len(others)} animation channel(s) of {POINTER} animate other properties than a "
        f"node's translation, rotation or scale (first: {show(others[0], 80)}): left out"
    ]


def _nothing_turns(document: Any) -> str:
    """What a file without a skeleton lacks, and what its animations change instead when
    that is morph-target weights only (a face or a creature's mesh that deforms)."""
    what = "no skin joints, VRM humanoid bones or animated nodes"
    paths = {
        channel_target(channel)[1]
        for animation in document.animations or []
        for channel in animation.channels or []
    }
    if "weights" in paths:
        what += "; its animation changes morph-target weights (blend shapes), which move no joint"
    return what


def _animated_nodes(document: Any, parents: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: for a file without skin (an animation exported without its mesh, by
    Blender or FBX2glTF), the nodes its channels turn or move, and the plain nodes (no mesh,
    camera or skin) below them, such as a head's end bone. Loose parts, each moved on its
    own and none below another, are no skeleton (:class:`ParseError`)."""
    nodes = document.nodes or []
    animated = np.zeros(len(nodes), dtype=bool)
    for animation in document.animations or []:
        for channel in animation.channels or []:
            node, path, _ = channel_target(channel)
            if path in ("translation", "rotation") and isinstance(node, int) and node >= 0:
                animated[node] = node < len(nodes)
    plain = np.array(
        [all(getattr(node, key, None) is None for key in _NOT_JOINT) for node in nodes], dtype=bool
    )
    # Nodes keyed one by one, none below another, each carrying meshes and no joint-like
    # (plain) node: rigid parts or props (a Blockbench model's groups), no body.
    carried = carriers(parents, animated)  # (N,) the animated node each node hangs from
    below = carried >= 0
    rigid = (
        not (animated & below).any()  # loose: none below another
        and not (plain & below).any()
        and set(carried[below]) == set(np.flatnonzero(animated))  # each carries something
    )
    parts = int(animated.sum()) if rigid else 0
    if parts >= MIN_MARKERS:
        shown = [nodes[i].name or f"node {i}" for i in np.flatnonzero(animated)[:5]]
        raise ParseError(
            f"the animation moves {parts} parts ({', '.join(shown)}"
            f"{' ...' if parts > 5 else ''}) each on its own, and the file has no skeleton: "
            "no skin, and no animated nodes that hang from one another (rigid parts or props "
            "keyed one by one: no bones between them, so no knees or elbows to map; a blocky "
            "figure is read once its parts hang from a skeleton)"
        )
    return with_plain_nodes_below(animated, plain, parents)


def _without_skeleton_moves(loaded: _Document, kept: np.ndarray) -> None:
    """Mark as not moving each animation that moves no node of the skeleton (``kept``: its
    joints and their ancestors): a prop's, a camera's, or a control's, as Blender writes one
    animation per animated object. It is then not read by default, nor a clip of its own."""
    skeleton = set(kept.tolist())
    loaded.animations = [
        replace(animation, moves=False)
        if animation.moves and not any(loaded.moved[p] & skeleton for p in parts)
        else animation
        for animation, parts in zip(loaded.animations, loaded.parts, strict=True)
    ]


class _Document:
    def __init__(self, data: bytes, limits: ParseLimits) -> None:
        self.document, blob, self.broken = load_document(data)
        self.buffers = buffers_of(self.document, blob)
        nodes = self.document.nodes or []
        if len(nodes) > MAX_NODES:
            raise LimitExceeded(
                f"the file has {len(nodes)} nodes, more than the limit of {MAX_NODES}"
            )
        self.limits = limits
        self.animations: list[Animation] = []
        self.rates: list[float] = []
        self.spans: list[tuple[float, float]] = []
        # The file's animations each exposed animation reads (one, or a take split by node).
        self.parts: list[list[int]] = []
        self._inputs: dict[int, np.ndarray] = {}
        animations = self.document.animations or []
        names = unique_names(
            [a.name or "" for a in animations], blank="animation {i}", repeat="{name} ({n})"
        )
        moved: list[set[int]] = []  # the nodes each animation moves
        for name, animation in zip(names, animations, strict=True):
            begin, end, rate = self._timing([animation])
            frames = int(np.floor((end - begin) * rate + 0.5)) + 1
            # (A target node is one of the file's nodes: gltf_schema.check_document.)
            targets = [channel_target(channel) for channel in animation.channels or []]
            # whether it moves a node (its translation, rotation or scale; not weights only)
            moved.append({node for node, path, _ in targets if path in _PATHS and node is not None})
            self.animations.append(Animation(name, frames, frames / rate, bool(moved[-1])))
            self.rates.append(rate)
            self.spans.append((begin, end))
            self.parts.append([len(self.parts)])
        self.moved = moved
        self._join_split_take(moved)

    def _join_split_take(self, moved: list[set[int]]) -> None:
        """One take written as one animation per node or part (COLLADA2GLTF's layout: each
        animation moves nodes no other moves, all over one span of time) is read as one
        animation: apart, each is a part of the body's motion and none is a clip (read
        alone, the first would be a still pose of a body that moves)."""
        if len(moved) < 2 or not all(moved):
            return
        seen: set[int] = set()
        for nodes in moved:
            if nodes & seen:
                return  # two animations move one node: takes of their own
            seen |= nodes
        animations = self.document.animations
        begin, end, rate = self._timing(animations)
        if any(abs(b - begin) > 0.5 / rate or abs(e - end) > 0.5 / rate for b, e in self.spans):
            return  # spans of their own: takes of their own
        frames = int(np.floor((end - begin) * rate + 0.5)) + 1
        first, last = self.animations[0].name, self.animations[-1].name
        name = f"{first} .. {last} (one take over {len(moved)} animations)"
        self.animations = [Animation(name, frames, frames / rate, True)]
        self.rates, self.spans, self.parts = [rate], [(begin, end)], [list(range(len(moved)))]

    def times(self, index: int) -> np.ndarray:
        if index not in self._inputs:
            keys = accessor_values(self.document, self.buffers, index)[:, 0]
            if not np.all(np.isfinite(keys)):
                raise ParseError(f"accessor {index}: non-finite key times (inf or NaN)")
            if keys.size > 1 and np.any(np.diff(keys) < 0):
                raise ParseError(f"accessor {index}: key times go backwards")
            self._inputs[index] = keys
        return self._inputs[index]

    def _timing(self, animations: list[Any]) -> tuple[float, float, float]:
        """First and last key time and the sampling rate of ``animations`` read as one."""
        keys = []
        for animation in animations:
            for sampler in animation.samplers or []:
                keys.append(self.times(sampler.input))
        if not keys or all(k.size == 0 for k in keys):
            return 0.0, 0.0, DEFAULT_FPS
        every = np.unique(np.concatenate(keys))
        begin, end = float(every[0]), float(every[-1])
        rate = DEFAULT_FPS
        if every.size > 1:
            steps = np.diff(every)
            # the mean spacing of evenly spaced keys: exact where one rounded step is not
            step = (end - begin) / (every.size - 1)
            # Key times are float32: ten minutes in, they are only good to 6e-5 s, so the
            # spacing is judged within a few of their units in the last place as well.
            slack = (
                1e-3 * step + 1e-6 + 4 * float(np.spacing(np.float32(max(abs(begin), abs(end)))))
            )
            if step > 0 and np.all(np.abs(steps - step) <= slack):
                key_rate = 1.0 / step
                if key_rate <= MAX_KEY_FPS:
                    rate = key_rate * max(1, int(np.ceil(MIN_FPS / key_rate - 1e-3)))
        return begin, end, rate


def list_gltf_animations(data: bytes, *, limits: ParseLimits = DEFAULT_LIMITS) -> list[Animation]:
    """The animations of a glTF / GLB / VRMA file, in file order."""
    return _Document(data, limits).animations


def read_gltf(
    data: bytes,
    *,
    animation: str | None = None,
    limits: ParseLimits = DEFAULT_LIMITS,
    still: bool = False,
) -> tuple[Motion, list[Animation], str]:
    """Read one animation of a glTF 2.0 / GLB / VRMA file (see the module docstring).

    Returns ``(motion, animations, chosen)`` and raises like
    :func:`~app.motion.formats.fbx.read_fbx` (:class:`~app.errors.NoAnimation` for a rig).
    With ``still``, a file with a skeleton and no animation gives its rest (bind) pose as
    one frame (a rig), animation name ``""``.
    """
    loaded = _Document(data, limits)
    document = loaded.document
    nodes = document.nodes or []
    count = len(nodes)
    parents = np.full(count, -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        for child in node.children or []:  # node indices: gltf_schema.check_document
            if parents[child] >= 0 or child == i:
                raise ParseError(f"node {child} has two parents (or is its own child)")
            parents[child] = i
    human = _human_bones(document)
    is_bone = np.zeros(count, dtype=bool)
    for skin in document.skins or []:
        for joint in skin.joints or []:
            if isinstance(joint, int) and 0 <= joint < count:
                is_bone[joint] = True
    for node in human:
        if 0 <= node < count:
            is_bone[node] = True
    if not is_bone.any():
        is_bone = _animated_nodes(document, parents)
    if not is_bone.any():
        if loaded.broken:  # what moved its nodes is an animation that could not be read
            first, problem = next(iter(loaded.broken.items()))
            raise ParseError(f"animation {loaded.animations[first].name!r}: {problem}")
        raise no_skeleton(loaded.animations, _nothing_turns(document))
    joinable = np.ones(count, dtype=bool)
    # Only the skeleton's nodes are sampled and counted (meshes, props, other trees are not).
    kept = skeleton_nodes(parents, is_bone, joinable)
    _without_skeleton_moves(loaded, kept)
    if not loaded.animations and still:  # a rig: its rest (bind) pose as one frame
        loaded.animations = [Animation("", 1, 0.0)]
        loaded.rates, loaded.spans, loaded.parts = [DEFAULT_FPS], [(0.0, 0.0)], [[0]]
        document.replace("animations", [{}])
    chosen = pick_animation(loaded.animations, animation, joints=int(is_bone.sum()))
    for part in loaded.parts[chosen]:
        if part in loaded.broken:
            raise ParseError(f"animation {loaded.animations[chosen].name!r}: {loaded.broken[part]}")
    warnings = choice_warnings(loaded.animations, chosen, animation)
    others_left = other_skeletons(parents, is_bone, kept)
    warnings += [others_left] if others_left else []
    warnings += [  # the file's other animations that could not be read: said, not fatal
        f"animation {loaded.animations[i].name!r} was not read: {problem}"
        for i, problem in loaded.broken.items()  # (a take joined over animations has none)
    ]
    info = loaded.animations[chosen]
    check_frame_budget(limits, info.frame_count, len(kept))
    position = np.full(count, -1, dtype=np.int64)  # node -> index among the kept ones
    position[kept] = np.arange(len(kept))
    for i in kept:
        check_node_transform(nodes[i].raw, int(i))
    rest = [_node_transform(nodes[i]) for i in kept]
    rest_t = np.array([r[0] for r in rest]).reshape(-1, 3)
    rest_r = np.array([r[1] for r in rest]).reshape(-1, 4)
    rest_s = np.array([r[2] for r in rest]).reshape(-1, 3)
    begin = loaded.spans[chosen][0]
    times = begin + np.arange(info.frame_count) / loaded.rates[chosen]
    tracks = {
        "translation": np.broadcast_to(rest_t, (len(times), len(kept), 3)).copy(),
        "rotation": np.broadcast_to(rest_r, (len(times), len(kept), 4)).copy(),
        "scale": np.broadcast_to(rest_s, (len(times), len(kept), 3)).copy(),
    }
    others: list[str] = []  # pointers to other properties than a node's transform
    channels = [
        (channel, document.animations[part].samplers or [])
        for part in loaded.parts[chosen]
        for channel in document.animations[part].channels or []
    ]
    for channel, samplers in channels:
        node, path, other = channel_target(channel)
        if other is not None:
            others.append(other)
        if path not in _PATHS or not isinstance(node, int) or not 0 <= node < count:
            continue  # morph weights, other properties, or no node: not the skeleton's
        if position[node] < 0:
            continue  # a mesh, a prop, a node of another tree: never part of the skeleton
        if not isinstance(channel.sampler, int) or not 0 <= channel.sampler < len(samplers):
            named = shown(channel.raw.get("sampler"))  # the JSON value, not its wrapper
            raise ParseError(f"a channel names sampler {named}, which does not exist")
        sampler = samplers[channel.sampler]
        keys = loaded.times(sampler.input)
        values = accessor_values(document, loaded.buffers, sampler.output)
        tracks[path][:, position[node]] = _sample_channel(
            keys, values, times, sampler.interpolation or "LINEAR", _PATHS[path], path
        )

    names = [node.name or f"node{i}" for i, node in enumerate(nodes)]
    for node, bone in human.items():
        if 0 <= node < count:
            names[node] = bone
    graph = NodeGraph(
        names=[names[i] for i in kept],
        parents=kept_parents(parents, kept),
        is_bone=is_bone[kept],
        joinable=joinable[kept],
        rest_translation=rest_t,
        rest_rotation=rest_r,
        rest_scale=rest_s,
        translation=tracks["translation"],
        rotation=tracks["rotation"],
        scale=tracks["scale"],
    )
    motion = motion_from_graph(
        graph,
        frame_time=1.0 / loaded.rates[chosen],
        source_format="gltf",
        length_unit="metres (glTF)",
        limits=limits,
        notes=scene_notes(info, [*warnings, *_pointer_warning(others)]),
    )
    if others_left:
        motion.notes[OTHER_SKELETONS] = others_left
    return motion, loaded.animations, info.name


def _sample_channel(
    keys: np.ndarray,
    values: np.ndarray,
    times: np.ndarray,
    interpolation: str,
    width: int,
    path: str,
) -> np.ndarray:
    """``(F, width)`` values of one channel at ``times`` (held constant outside the keys)."""
    cubic = interpolation == "CUBICSPLINE"
    per_key = 3 if cubic else 1
    if values.shape[1] != width or len(values) != per_key * len(keys) or len(keys) == 0:
        raise ParseError(
            f"an animation channel of {path} has {len(values)} values of {values.shape[1]} "
            f"numbers for {len(keys)} keys ({interpolation})"
        )
    if not np.all(np.isfinite(values)):
        raise ParseError(f"non-finite number (inf or NaN) in an animated {path}")
    if cubic:
        tangent_in, points, tangent_out = values[0::3], values[1::3], values[2::3]
    else:
        points = values
    if len(keys) == 1:
        return np.broadcast_to(points[0], (len(times), width)).copy()
    clipped = np.clip(times, keys[0], keys[-1])
    segment = np.clip(np.searchsorted(keys, clipped, side="right") - 1, 0, len(keys) - 2)
    t0, t1 = keys[segment], keys[segment + 1]
    span = np.where(t1 > t0, t1 - t0, 1.0)
    u = np.clip((clipped - t0) / span, 0.0, 1.0)[:, None]
    a, b = points[segment], points[segment + 1]
    if interpolation == "STEP":
        return np.where(u >= 1.0, b, a)
    if cubic:
        u2, u3 = u * u, u * u * u
        d = span[:, None]
        out = (
            (2 * u3 - 3 * u2 + 1) * a
            + (u3 - 2 * u2 + u) * d * tangent_out[segment]
            + (-2 * u3 + 3 * u2) * b
            + (u3 - u2) * d * tangent_in[segment + 1]
        )
        return out
    if path == "rotation":
        return _slerp(a, b, u)
    return a + (b - a) * u


def _slerp(a: np.ndarray, b: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical interpolation of ``(F, 4)`` quaternions (shortest path)."""
    a = a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-12)
    b = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
    dot = np.sum(a * b, axis=1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    angle = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(angle)
    near = sin < 1e-6
    safe = np.where(near, 1.0, sin)
    wa = np.where(near, 1.0 - u, np.sin((1.0 - u) * angle) / safe)
    wb = np.where(near, u, np.sin(u * angle) / safe)
    return wa * a + wb * b
