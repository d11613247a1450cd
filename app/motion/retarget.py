"""One humanoid's motion on another's skeleton, through the canonical joints both map to.

The structural mapping (:mod:`app.motion.skeleton_map`) says, for both skeletons, which joint
is the pelvis, each hip, knee, shoulder... That is all retargeting needs.

**Rotations, aligned by the two reference poses.** Each skeleton has a reference pose: its
rest pose, or for a rig whose rest pose is not a standing figure the pose the mapper read it
from. A driven target joint (one per canonical bone: pelvis, spine, chest, neck, head,
clavicles, upper arms, forearms, hands, thighs, shins, feet, toes where both have them)
turns as its source joint turned since the source's reference pose::

    G_target(f) = W^T · G_source(f) · Q_source^T · A · Q_target

``Q`` are the joints' world rotations in the reference poses, ``A`` takes the target's
reference bone onto the source's: first the whole body (``B_source B_target^T`` from the
two bodies' lateral/up/forward axes, fixed to the pelvis joint as the describer reads them,
so the rig's pelvis frame is the source's in every frame and a trunk leaning in the
reference pose stays leaning), then the smallest rotation bringing the bone's
direction onto the source bone's. So a T-pose rig driven by an A-pose capture lifts its arms
to where the capture's are, and since the smallest rotation has no twist about the bone, a
bone's roll never twists. ``W`` changes world axes from the source's up to the target's
(Y-up capture on a Z-up rig), a quarter turn or none.

**Head and hand.** The head joint turns as the source's head joint does, whatever lies
beyond either (a head-top end effector on one rig, nothing on the other): a chain's end is
only aimed at, and before this the head of such a pair stayed at rest on its neck, so the
re-uploaded clip's head had no motion at all (``kinetic``'s head DOFs 0). Its reference
alignment takes its up (head joint -> top of the head, or neck -> head) onto the source
head's. The hand's orientation is carried by the palm — the first joint past the wrist
where the fingers branch, or the joint the hand tip hangs from — which is driven by the
source's palm, so a rig that bends the hand below its wrist joint (wrist -> hand ->
fingers) passes that bend on. Where the branch is a hand and a thumb starting at one place
(the CMU skeletons: ``rwrist`` -> ``rhand``, ``rthumb``), the hand is the palm: the joint
above them only twists the forearm's end (:func:`~app.motion.retarget_joints.palm`).

**Directions exact.** Where the source has joints the target lacks between two canonical
joints (a spine of five against one of three), the transferred rotation alone would point
the target's bone a little off; a last per-frame swing turns each driven bone (except the
hand, whose direction depends on the fingers) onto the source bone's world direction.
A limb bone both split into as many pieces (twist joints at other points) then turns as one,
so the bone from mapped joint to mapped joint points as the source's
(:func:`~app.motion.retarget_transfer.turn_split_limbs`).

**The trunk's chord.** Where the two skeletons' spine, chest and neck joints sit at other
heights, spine bones pointing as the source's add up to another pelvis -> neck, the chord
the describer reads; the rig's spine joint then turns so that chord is the source's, the
chest and what hangs from it keeping their directions
(:func:`~app.motion.retarget_trunk.aim_trunk_chord`).

**Everything else at rest.** Unmapped target joints (fingers, face, twist bones, a static
root above the pelvis) keep their reference-pose local rotation; offsets are the rig's own,
so bone lengths are exactly the rig's.

**Root.** The pelvis travels as the source's pelvis, scaled about the world origin by the
ratio of the legs' bone paths (hip -> knee -> ankle), then moved up or down per frame so that
the target's foot points that are on the floor in the source (the standing foot) are where
the source's are (scaled), and nothing is below the source's lowest point: feet on the
source's floor, neither sinking nor floating, and a swinging foot that is lower on the rig
(a longer shin) does not lift the standing one off the floor. At frames with no point on
the floor (a jump) the lowest points match. A pelvis below a static top joint gets the
travel as per-frame offsets.

**Planted feet.** Where the legs' proportions differ from the source's (a longer shin, wider
hips), the same directions and the scaled travel move a planted foot over the floor. The
pelvis's horizontal path is corrected instead of the legs: at each frame where foot points
(ankles, toes) are on the floor in both (within :data:`ON_FLOOR` of the body height), the path
takes the mean of how much farther they moved over the floor than the source's (scaled) did
back, so a foot on the floor moves as the source's moves — not at all when the source's
stands, a slide where the source slides. Every bone keeps the source's direction. At steps
with no foot point on the floor (a run's flight) the path goes back toward the scaled
source's, evenly over the gap and no faster than the holds moved it: what the holds gathered
over a contact does not carry over as travel the source never had
(:func:`~app.motion.retarget_floor.planted_feet_offsets`). A walk is always on a foot, so
what carries it is the stride: a foot longer for its legs than the source's (a toe tip
where the source has the ball of its foot) first has its roll over the toe fitted, the
ankle coming forward over the toe as far as the source's does, so the body is carried as
far as the scaled source's (:func:`~app.motion.retarget_stride.fit_planted_roll`).

What the pelvis cannot hold (two points down that disagree: both feet, or the heel and
toe of a long foot) the legs take up: each planted foot (contact from the source) is held
where the source's stands by turning its leg about the hip, by at most a few degrees so
limb directions stay within the quality bar (:mod:`app.motion.retarget_feet`).

**Swinging feet clear the floor.** A foot long for its leg (a toe tip where the source has
the ball of its foot) points its toe lower than the source's when it swings toe-down; where
the source's toe is off the floor and the target's is not, the foot is pitched up about the
ankle until the toe is off the floor too (then the pelvis goes back on the floor). Only that
far, not to the source toe's height: on a foot long for its leg that took a 30-50 degree
pitch at every toe-off, an ankle motion the source does not have
(:func:`~app.motion.retarget_floor.clear_swinging_toes`).

A capture with left-handed geometry (``SkeletonMap.mirrored``) is first reflected as the
describer reflects it, so left stays left.

This module is the public entry; the parts live beside it: which joints are driven
(:mod:`app.motion.retarget_joints`), the reference poses and alignments
(:mod:`app.motion.retarget_reference`), the per-joint rotation transfer
(:mod:`app.motion.retarget_transfer`), the trunk's chord (:mod:`app.motion.retarget_trunk`),
the pelvis's path and the feet on the floor
(:mod:`app.motion.retarget_floor`, :mod:`app.motion.retarget_feet`), a planted foot's roll
(:mod:`app.motion.retarget_stride`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from app.motion.body import body_height, carried_frames, pelvis_basis, rest_axes_hold
from app.motion.gravity import clip_vertical
from app.motion.ground import snap_axis
from app.motion.joint_copies import folded_copies
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion
from app.motion.retarget_floor import place_pelvis
from app.motion.retarget_joints import driven_joints
from app.motion.retarget_reference import (
    axis_change,
    leg_length,
    reference_frame,
    reference_pose,
    rest_of,
    swing,
)
from app.motion.retarget_transfer import driven_rotations, target_rotations
from app.motion.retarget_trunk import aim_trunk_chord
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap
from app.motion.transforms import reflect

_TINY = 1e-9


def retarget(
    source: Motion,
    source_map: SkeletonMap,
    target: Motion,
    target_map: SkeletonMap,
    *,
    hold_feet: bool = True,
) -> Motion:
    """``source``'s motion on ``target``'s skeleton (see the module docstring).

    Parameters
    ----------
    source:
        The clip (``F`` frames, ``J_s`` joints) and ``source_map`` its mapping.
    target:
        The rig: its skeleton and, in frame 0, its reference pose (local rotations; the
        identity for a rig whose rest pose is a standing figure); ``target_map`` its mapping.
    hold_feet:
        Whether the legs hold planted feet (:mod:`app.motion.retarget_feet`); off, only the
        pelvis's path does.

    Returns
    -------
    Motion
        ``F`` frames at the source's rate on ``target.skeleton`` (same names, parents,
        offsets, end sites), in the target's units and world axes.
    """
    if target_map.mirrored:
        mirrored = retarget(
            source,
            source_map,
            reflect(target, axis=target_map.mirror_axis),
            _unmirrored(target_map),
            hold_feet=hold_feet,
        )
        return reflect(mirrored, axis=target_map.mirror_axis)
    if source_map.mirrored:
        source = reflect(source, axis=source_map.mirror_axis)

    source = folded_copies(source)  # the pelvis's turn where the body reads it (as described)
    driven, limbs = driven_joints(source, source_map, target, target_map)
    # Only the source joints the retarget reads: driven, aimed at, canonical.
    s_needed = {int(j) for j in source_map.joints}
    for d in driven:
        s_needed.update(j for j in (d.source, d.source_aim) if j is not None)
        if d.align_bones is not None:
            s_needed.update(d.align_bones[2:])
    s_rot, s_pos = forward_kinematics(source, joints=sorted(s_needed))  # (F, Js, 3, 3), (F, Js, 3)
    s_ref = reference_frame(source_map)
    if s_ref is None:
        s_ref_rot = np.broadcast_to(np.eye(3), s_rot.shape[1:])
        _, rest = forward_kinematics(rest_of(source))
        s_ref_pos = rest[0]
    else:
        s_ref = min(max(s_ref, 0), source.frame_count - 1)
        s_ref_rot, s_ref_pos = s_rot[s_ref], s_pos[s_ref]
    t_ref_motion = target.slice_frames(0, 1)
    t_ref_motion = Motion(
        skeleton=target.skeleton,
        frame_time=target.frame_time,
        root_translation=t_ref_motion.root_translation,
        local_rotations=t_ref_motion.local_rotations,
    )
    t_ref_rot_all, t_ref_pos_all = forward_kinematics(t_ref_motion)
    t_ref_rot, t_ref_pos = t_ref_rot_all[0], t_ref_pos_all[0]

    s_canon = s_pos[:, source_map.joints]  # (F, C, 3)
    # The body's axes in each reference pose as the describer reads them: fixed to the
    # pelvis joint (app.motion.body), not the reference pose's own trunk, which carries
    # that pose's bend (a take's first frame, leaning into a tired walk).
    s_pelvis = int(source_map.joints[CANONICAL_INDEX["pelvis"]])
    t_pelvis = int(target_map.joints[CANONICAL_INDEX["pelvis"]])
    b_source = s_ref_rot[s_pelvis] @ _pelvis_axes(source, source_map)
    b_target = t_ref_rot[t_pelvis] @ _pelvis_axes(target, target_map)
    body = b_source @ b_target.T  # target reference body -> source reference body
    # The source's world up as the describer reads it (app.motion.body's world_up): the
    # coordinate axis nearest the pelvis frame's mean up. The trunk's mean direction
    # (pelvis -> neck) snapped to the forward axis in a clip bent over for most of its
    # frames (a sneak, a crawl, a fall: 45+ degrees), which stood the output on its face:
    # a quarter turn off on a rig of the other up axis, the re-upload read as a quadruped.
    s_up = world_up(source, source_map, s_rot[:, s_pelvis], s_canon)
    t_up = snap_axis(b_target[:, 1])
    world = axis_change(t_up, s_up)  # target world axes -> source world axes

    rotation = driven_rotations(
        driven, limbs, s_rot, s_pos, s_ref_rot, s_ref_pos, t_ref_rot, t_ref_pos, body, world
    )
    parents = target.skeleton.parents
    rest_axes = rest_axes_hold(
        target, target_map.joints, rest_is_a_figure=target_map.pose == "rest pose"
    )
    aim_trunk_chord(
        driven,
        rotation,
        parents,
        t_ref_rot,
        t_ref_pos,
        s_pos,
        source_map,
        target_map,
        world,
        rest_axes=rest_axes,
    )
    rotations = target_rotations(driven, rotation, t_ref_rot, parents)
    local = rotations.local
    pelvis = int(target_map.joints[CANONICAL_INDEX["pelvis"]])
    # A pelvis below a static top joint: the world rotation its per-frame offset is in.
    above_pelvis = None if pelvis <= 0 else rotations.world_of(parents[[pelvis]])[:, 0]

    def assemble(pelvis_at: np.ndarray) -> Motion:
        return _assemble(
            target, source.frame_time, local, above_pelvis, pelvis, pelvis_at, t_ref_pos
        )

    pelvis_rot = rotations.world_of(np.array([pelvis]))[:, 0]
    pelvis_at = place_pelvis(
        source,
        source_map,
        target,
        target_map,
        s_canon,
        world,
        t_up,
        local,
        pelvis_rot,
        assemble,
        hold_feet=hold_feet,
    )
    return assemble(pelvis_at)


def _assemble(
    target: Motion,
    frame_time: float,
    local: np.ndarray,
    above_pelvis: np.ndarray | None,
    pelvis: int,
    pelvis_at: np.ndarray,
    ref_pos: np.ndarray,
) -> Motion:
    """The output motion with the pelvis at ``pelvis_at`` ``(F, 3)`` (the top joint's
    translation, or the pelvis's per-frame offset under a static top joint)."""
    skeleton = target.skeleton
    frames = local.shape[0]
    if pelvis == 0:
        root = pelvis_at
        translations = None
    else:
        root = np.broadcast_to(ref_pos[0], (frames, 3)).copy()
        # Joints above the pelvis are at their reference pose: their positions are fixed.
        assert above_pelvis is not None  # the pelvis's parent's world rotation, (F, 3, 3)
        parent = int(skeleton.parents[pelvis])
        translations = np.broadcast_to(skeleton.offsets, (frames, *skeleton.offsets.shape)).copy()
        translations[:, 0] = root
        translations[:, pelvis] = (
            np.swapaxes(above_pelvis, -1, -2) @ (pelvis_at - ref_pos[parent])[:, :, None]
        )[:, :, 0]
    return Motion(
        skeleton=skeleton,
        frame_time=frame_time,
        root_translation=root,
        local_rotations=local,
        local_translations=translations,
        source_format=target.source_format,
        length_unit=target.length_unit,
        notes={},
    )


def world_up(
    motion: Motion,
    mapping: SkeletonMap,
    pelvis_rotations: np.ndarray | None = None,
    positions: np.ndarray | None = None,
) -> np.ndarray:
    """``(3,)`` the world's up in ``motion`` as :mod:`app.motion.body` reads it: the signed
    coordinate axis nearest the pelvis frame's mean up over the frames (``pelvis_rotations``
    ``(F, 3, 3)``, the pelvis joint's world rotations, and ``positions`` ``(F, C, 3)``, the
    canonical joints' world positions, when already computed). Not the trunk's mean
    direction: a clip bent over for most of its frames (a sneak, a fall) has its pelvis ->
    neck nearer the forward axis than the up one; a take lying along the floor (a crawl)
    takes another axis (its standing rest pose's, or one it stands along for a part of the
    take) where the floor says so (:mod:`app.motion.gravity`), as the describer does; exports
    read it too (:func:`app.motion.root_motion.vertical`). A pelvis whose rotation moves no bone
    (its children turn it back) is read from the joints, as the describer reads it
    (:func:`~app.motion.body.carried_frames`)."""
    if pelvis_rotations is None or positions is None:
        rotations, world = forward_kinematics(motion, joints=mapping.joints)
        pelvis_rotations = rotations[:, int(mapping.joints[CANONICAL_INDEX["pelvis"]])]
        positions = world[:, mapping.joints]
    frames = carried_frames(pelvis_rotations @ _pelvis_axes(motion, mapping), positions)
    height = body_height(motion, mapping.joints, head_joint=mapping.head_joint, held=mapping.held)
    take_up = snap_axis(frames[:, :, 1].mean(axis=0))
    return clip_vertical(take_up, motion.skeleton, mapping, positions, height, frames[:, :, 1])


def _pelvis_axes(motion: Motion, mapping: SkeletonMap) -> np.ndarray:
    """``(3, 3)`` body axes (columns lateral, up, forward) in ``motion``'s pelvis joint
    coordinates, as :func:`app.motion.body.build_body` finds them for the clip's pelvis
    frames: from the rest pose, or for a rig whose rest pose is not a standing figure from
    the frames where they disagree with it.

    Aligning the two reference poses by these axes gives the target's pelvis the source's
    pelvis frame in every frame, so whatever the describer reads relative to the pelvis (the
    trunk's lean, the limbs' directions) arrives as the source has it. Aligning by the
    reference pose's own trunk (pelvis -> neck) instead took a reference frame's spine bend
    for upright: a take whose first frame leans forward (a tired walk) lost that lean in
    every frame, the pelvis tilted back by as much."""
    return pelvis_basis(motion, mapping.joints, rest_is_a_figure=mapping.pose == "rest pose")


def _unmirrored(mapping: SkeletonMap) -> SkeletonMap:
    return replace(mapping, mirrored=False)


__all__ = [
    "axis_change",
    "leg_length",
    "reference_frame",
    "reference_pose",
    "retarget",
    "swing",
    "world_up",
]
