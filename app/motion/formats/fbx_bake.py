"""The animation bake of Blender's FBX exporter, computed for all frames at once in numpy.

**Import only where bpy runs** (the export workers, through
:mod:`app.motion.formats.fbx_writer`).

Blender's exporter (``io_scene_fbx``) bakes an armature's animation by stepping the scene
through every frame (``scene.frame_set``) and decomposing every bone's matrix in Python: 2-13
ms per frame for a 38-joint skeleton on the shared development machine, 16-90 s for a minute
at 120 fps (bench/bench_fbx_bake.py). Every value it reads
there is already known to the writer: a bone's local transform in the file is its rest
transform relative to its parent (the exporter's own ``fbx_object_matrix(rest=True)``) times
the pose key the writer set, ``[basis | location]``. :func:`numpy_bake` swaps the exporter's
``fbx_animations_do`` for one that computes those transforms, splits them into location,
XYZ Euler angles (each frame's the solution nearest the previous frame's, as the exporter's
``to_euler(compat)`` picks) and scale, and hands them to the exporter's own curve code (keys,
simplification, the animation stack): the file is still written by Blender's exporter.

It takes over only the scene it expects — one armature object and its bones, nothing else,
one key per frame — and first checks the scene, posed at rest (the static transforms the
file gets), against the exporter's own rest transforms; it refuses anything else (another
Blender version composing bones otherwise), and the writer then exports again with the
exporter's own bake, slow but right.
Its values are double precision where Blender's are single: they agree to Blender's
rounding (a few 1e-4 cm on a bone's offset once a minute's walk has taken the root tens of
metres away, where Blender's armature-space matrices lose digits).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

# The exporter's transforms are Blender's single-precision ones: agreement to this many
# times the largest entry is agreement.
MATCH_TOLERANCE = 1e-4
_FLT_EPSILON = float(np.finfo(np.float32).eps)


@dataclass
class BakeOutcome:
    """What :func:`numpy_bake` did: ``refused`` says why it left a scene unbaked, else None."""

    refused: str | None = None


@contextmanager
def numpy_bake(
    bone_names: Sequence[str], basis: np.ndarray, locations: Mapping[int, np.ndarray]
) -> Iterator[BakeOutcome]:
    """Within the block, Blender's FBX exporter bakes the armature's animation from
    ``basis`` ``(F, J, 3, 3)`` (each bone's pose rotation in its rest frame) and
    ``locations`` (joint index -> ``(F, 3)`` pose location; other bones stay at 0) — bones
    named ``bone_names``, posed at the scene's current frame — instead of stepping the scene.

    A scene it does not expect gets no animation and the yielded outcome's ``refused`` says
    why: the caller exports it again with the exporter's own bake (an exception raised here
    would not cross Blender's operator call)."""
    from io_scene_fbx import export_fbx_bin

    original = export_fbx_bin.fbx_animations_do
    index = {name: j for j, name in enumerate(bone_names)}
    outcome = BakeOutcome()

    def fbx_animations_do(
        scene_data: Any,
        ref_id: Any,
        f_start: float,
        f_end: float,
        start_zero: bool,
        objects: Any = None,
        force_keep: bool = False,
    ) -> Any:
        if ref_id is not None or objects is not None:
            outcome.refused = "an animation stack per action or strip"
            return None
        baked = _bake(scene_data, f_start, f_end, index, basis, locations)
        if isinstance(baked, str):
            outcome.refused = baked
            return None
        return _stack(export_fbx_bin, scene_data, baked, f_start, f_end, start_zero, force_keep)

    export_fbx_bin.fbx_animations_do = fbx_animations_do
    try:
        yield outcome
    finally:
        export_fbx_bin.fbx_animations_do = original


def _bake(
    scene_data: Any,
    f_start: float,
    f_end: float,
    index: Mapping[str, int],
    basis: np.ndarray,
    locations: Mapping[int, np.ndarray],
) -> dict[Any, tuple[np.ndarray, np.ndarray, np.ndarray]] | str:
    """Each object's ``(F, 3)`` location, rotation (XYZ Euler, radians) and scale, keyed by
    the exporter's object wrapper; why not, when the scene is not the one expected."""
    settings = scene_data.settings
    frames = basis.shape[0]
    if settings.bake_anim_step != 1.0 or (f_start, f_end) != (0, frames - 1):
        return f"frames {f_start}..{f_end} by {settings.bake_anim_step}, not 0..{frames - 1}"
    if scene_data.data_deformers_shape or scene_data.data_cameras:
        return "shape keys or cameras"
    objects = [o for o in scene_data.objects if not o.parented_to_armature]
    if any(o.is_dupli for o in objects):
        return "instanced objects"
    # A key [R | t] in the exporter's bone axes: C^-1 [R | t] C, C a rotation (or None).
    correction = settings.bone_correction_matrix
    fix = np.eye(3) if correction is None else np.array(correction)[:3, :3]
    unfix = fix.T
    rest = np.empty((len(objects), 4, 4))  # each object's parent-relative rest (bones)
    joints = np.zeros(len(objects), dtype=np.intp)  # each bone's joint (0 for the armature)
    static: list[int] = []  # the armature object: not animated itself
    for n, ob_obj in enumerate(objects):
        if ob_obj.is_bone:
            joint = index.get(ob_obj.bdata.name)
            if joint is None:
                return f"a bone {ob_obj.bdata.name!r} without keys"
            joints[n] = joint
            rest[n] = np.array(ob_obj.fbx_object_matrix(scene_data, rest=True))
        elif ob_obj.is_object and ob_obj.bdata.type == "ARMATURE":
            rest[n] = np.array(ob_obj.fbx_object_matrix(scene_data))
            static.append(n)
        else:
            return f"an object of type {ob_obj.bdata.type}"
    # local = rest @ key: (N, F, 3, 3) and (N, F, 3) in the file's frames.
    keys = np.swapaxes(basis[:, joints], 0, 1)  # (N, F, 3, 3)
    if correction is not None:
        keys = unfix @ keys @ fix
    linear = rest[:, None, :3, :3] @ keys
    del keys  # peak memory: a long clip's (N, F, 3, 3) arrays are hundreds of MB each
    location = np.broadcast_to(rest[:, None, :3, 3], linear.shape[:-1]).copy()
    for n in np.flatnonzero(np.isin(joints, list(locations))).tolist():
        if n not in static:
            moved = locations[int(joints[n])] @ unfix.T  # (F, 3) C^-1 t
            location[n] += moved @ rest[n, :3, :3].T
    linear[static] = rest[static, None, :3, :3]
    # The scene is posed at rest (identity keys): each object's transform must be its rest.
    for n, ob_obj in enumerate(objects):
        posed = np.array(ob_obj.fbx_object_matrix(scene_data))
        scale = max(1.0, float(np.abs(posed).max()))
        if np.abs(rest[n, :3] - posed[:3]).max() > MATCH_TOLERANCE * scale:
            return f"{ob_obj.name!r} posed otherwise than at rest"
    # Blender's mat4_to_loc_rot_size: the columns' lengths, negated with the rotation when
    # the matrix mirrors.
    size = np.sqrt(np.einsum("...ij,...ij->...j", linear, linear))  # (N, F, 3)
    mirrors = np.einsum("...i,...i->...", linear[..., 0], np.cross(linear[..., 1], linear[..., 2]))
    size[mirrors < 0] *= -1.0
    del mirrors
    rotation = linear
    rotation /= size[..., None, :]  # in place: the linear part is not needed any more
    # The first frame's Euler angles as Blender's to_euler gives them alone (the solution
    # with the smaller angles), as when the exporter bakes a scene whose static transforms
    # are that frame's; each next frame's nearest the previous.
    first = compatible_eulers(rotation[:, :1], np.zeros((len(objects), 3)))[:, 0]
    euler = compatible_eulers(rotation, first)
    return {ob_obj: (location[n], euler[n], size[n]) for n, ob_obj in enumerate(objects)}


def compatible_eulers(rotation: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """``(N, F, 3)`` XYZ Euler angles (radians) of rotation matrices ``(N, F, 3, 3)``, each
    frame's the one of the two solutions (wrapped by whole turns) nearest the previous
    frame's, starting from ``previous`` ``(N, 3)`` — Blender's
    ``Quaternion.to_euler('XYZ', compat)`` (``mat3_normalized_to_compatible_eul``) frame
    after frame, so importers interpolate between keys the short way."""
    m = rotation
    cy = np.hypot(m[..., 0, 0], m[..., 1, 0])
    candidates = np.empty((2, *m.shape[:-2], 3))  # (2, N, F, 3) the two solutions
    first, second = candidates
    first[..., 0] = np.arctan2(m[..., 2, 1], m[..., 2, 2])
    first[..., 1] = np.arctan2(-m[..., 2, 0], cy)
    first[..., 2] = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    # The other solution, atan2 of the negated arguments, from the first: x and z half a
    # turn round, y mirrored about ±90° (the signs of zeros kept, as atan2 keeps them).
    second[..., 0::2] = first[..., 0::2] - np.copysign(np.pi, first[..., 0::2])
    second[..., 1] = np.copysign(np.pi, first[..., 1]) - first[..., 1]
    gimbal = cy <= 16.0 * _FLT_EPSILON  # pitch at ±90°: one solution, no roll
    if gimbal.any():
        locked = m[gimbal]
        first[gimbal, 0] = np.arctan2(-locked[:, 1, 2], locked[:, 1, 1])
        first[gimbal, 2] = 0.0
        second[gimbal] = first[gimbal]
    start = np.asarray(previous, dtype=np.float64)  # (N, 3)
    # Wrapping a solution by whole turns to within half a turn of the previous angles
    # (compatible_eul) makes its distance to them the distance on the circle; so which
    # solution a frame takes depends only on which one the frame before took (not on how
    # often it was wrapped): per frame, a map of {0, 1} onto itself, composed in one pass.
    takes_second = np.empty((2, *candidates.shape[1:3]), dtype=bool)  # (previous, N, F)
    takes_second[:, :, 0] = _circle(candidates[1, :, 0], start) < _circle(
        candidates[0, :, 0], start
    )
    for was in (0, 1):
        takes_second[was, :, 1:] = _circle(candidates[1, :, 1:], candidates[was, :, :-1]) < (
            _circle(candidates[0, :, 1:], candidates[was, :, :-1])
        )
    fixed = takes_second[0] == takes_second[1]  # the frame's choice whatever came before
    swaps = takes_second[0] & ~takes_second[1]  # the other solution than the frame before's
    frames = np.arange(candidates.shape[2])
    last_fixed = np.maximum.accumulate(np.where(fixed, frames, 0), axis=-1)  # (N, F)
    swap_count = np.cumsum(swaps, axis=-1)
    rows = np.arange(candidates.shape[1])[:, None]
    choice = takes_second[0][rows, last_fixed] ^ (
        (swap_count - swap_count[rows, last_fixed]) % 2 == 1
    )
    chosen = np.where(choice[..., None], candidates[1], candidates[0])  # (N, F, 3)
    # ... then each angle wrapped by whole turns to within half a turn of the frame
    # before's: the turns taken off add up along the frames.
    steps = np.diff(np.concatenate([start[:, None], chosen], axis=1), axis=1)
    turns = np.cumsum(np.floor(steps / (2.0 * np.pi) + 0.5), axis=1)
    return chosen - (2.0 * np.pi) * turns


def _circle(angles: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``(...)`` the summed distances on the circle of ``(..., 3)`` angles to others, both
    within ``[-pi, pi]`` (``atan2``'s, as Blender's ``to_euler`` gives too)."""
    gap = np.abs(angles - reference)
    return np.minimum(gap, 2.0 * np.pi - gap).sum(axis=-1)


def _stack(
    exporter: Any,
    scene_data: Any,
    baked: Mapping[Any, tuple[np.ndarray, np.ndarray, np.ndarray]],
    f_start: float,
    f_end: float,
    start_zero: bool,
    force_keep: bool,
) -> Any:
    """The rest of the exporter's ``fbx_animations_do``: its curves, simplification and
    animation stack, from the baked values (the same steps in the same order)."""
    settings = scene_data.settings
    scene = scene_data.scene
    simplify_fac = settings.bake_anim_simplify_factor
    bake_step = settings.bake_anim_step
    wrapper = exporter.AnimationCurveNodeWrapper
    frames = np.arange(f_start, np.nextafter(f_end, np.inf), step=bake_step)
    fps = scene.render.fps / scene.render.fps_base
    times = frames - f_start if start_zero else frames
    times = (times / fps * exporter.FBX_KTIME).astype(np.int64)

    all_anims: list[Any] = []
    for ob_obj, (location, euler, scale) in baked.items():
        loc, rot, size, _matrix, _rotation = ob_obj.fbx_object_tx(scene_data)
        rot_deg = tuple(exporter.convert_rad_to_deg_iter(rot))
        force_key = (simplify_fac == 0.0) or (ob_obj.is_bone and settings.bake_anim_use_all_bones)
        sek = settings.bake_anim_force_startend_keying
        anims = (
            wrapper(ob_obj.key, "LCL_TRANSLATION", force_key, sek, loc),
            wrapper(ob_obj.key, "LCL_ROTATION", force_key, sek, rot_deg),
            wrapper(ob_obj.key, "LCL_SCALING", force_key, sek, size),
        )
        for anim, values in zip(anims, (location, np.rad2deg(euler), scale), strict=True):
            anim.set_keyframes(times, np.ascontiguousarray(values.T))
        all_anims.extend(anims)

    animations: dict[Any, Any] = {}
    for anim in all_anims:
        anim.simplify(simplify_fac, bake_step, force_keep)
        if not anim:
            continue
        for obj_key, group_key, group, fbx_group, fbx_gname in anim.get_final_data(
            scene, None, force_keep
        ):
            anim_data = animations.setdefault(obj_key, ("dummy_unused_key", {}))
            anim_data[1][fbx_group] = (group_key, group, fbx_gname)

    astack_key = exporter.get_blender_anim_stack_key(scene, None)
    alayer_key = exporter.get_blender_anim_layer_key(scene, None)
    name = scene.name.encode()
    if start_zero:
        f_end -= f_start
        f_start = 0.0
    return (astack_key, animations, alayer_key, name, f_start, f_end) if animations else None


__all__ = ["BakeOutcome", "compatible_eulers", "numpy_bake"]
