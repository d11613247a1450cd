"""One pose's mapping: every canonical joint placed once head, hands and feet are chosen."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from app.motion.mapping.arms import _ArmRules
from app.motion.mapping.canonical import CANONICAL_JOINTS, SkeletonMap, detect_family
from app.motion.mapping.hypotheses import _hypotheses, _Known, _NotHumanoid
from app.motion.mapping.named import NAMES_NOT_FOLLOWED
from app.motion.mapping.runs import _ARM, _LEG
from app.motion.mapping.sides import _SideRules
from app.motion.mapping.state import _HEAD_END_MIN, _Limb
from app.motion.mapping.vectors import _length, _unit

# Head/hands/feet choices walked, cheapest first, before giving up on a pose.
_TRIED_CHOICES = 12


def _map_pose(
    known: _Known,
    pose: np.ndarray,
    label: str,
    others: Callable[[], list[np.ndarray]] = list,
    lifted: bool = False,
) -> SkeletonMap:
    """The mapping ``pose`` shows (``others``: more poses of the clip, which vote on the
    sides with it; ``lifted``: the body may stand on one foot, see
    :data:`~app.motion.mapping.hypotheses._LIFTED_FOOT_DROP`)."""
    tree = known.tree
    extent = float(np.linalg.norm(np.ptp(pose[tree.body_joints], axis=0)))
    if not extent > 0:
        raise _NotHumanoid("every joint of the pose is at one point: no shape to map")
    valid, reason = _hypotheses(known, pose, extent, lifted)
    if not valid:
        raise _NotHumanoid(f"not a whole humanoid: {reason}")
    # The cheapest choice whose limbs have knees and elbows (an IK target hanging from the
    # root may pass for a leg until its chain is walked).
    first: _NotHumanoid | None = None
    for body in sorted(valid, key=lambda b: b.cost)[:_TRIED_CHOICES]:
        try:
            return _Mapper(tree, pose, extent, body, label, others).run()
        except _NotHumanoid as problem:
            first = first or problem
    assert first is not None
    raise first


class _Mapper(_ArmRules, _SideRules):
    """Places every canonical joint once head, hands and feet are known."""

    def run(self) -> SkeletonMap:
        tree, body = self.tree, self.body
        self.put("pelvis", body.pelvis, "structure: where the legs and the spine meet")
        self.put("chest", body.chest, "structure: where the arms branch off the spine")
        self.derived.append("chest")
        self.map_head()
        self.map_spine()
        shoulders = tree.lca(*body.hands)
        if shoulders != body.chest:
            # The arms part on a bone of their own beside the neck: that is where a
            # person's chest carries them (the spine joint below stands for the spine).
            self.put("chest", shoulders, "structure: where the arms branch, beside the neck")
        legs = [
            self.map_leg(f) if f != body.lifted else self.lifted_leg(body.feet, f)
            for f in body.feet
        ]
        # Each leg is its own chain from the hip down: a hip at or above the point where the
        # two leg chains part is one limb forking (fingers of one hand), not two legs.
        if not all(self.own_hip(leg) for leg in legs):
            raise _NotHumanoid(
                "the two legs share their hip: no two separate legs below the pelvis"
            )
        # How far apart the legs start: at the hips, or, where the hip joints both sit at
        # the pelvis, at the knees (at rest a person's knees stand about as far apart as the
        # hip joints; a gap of zero would let a collar's root pass for a shoulder).
        coincide = self.same_place(legs[0]["hip"], legs[1]["hip"])
        part = "knee" if coincide else "hip"
        poses = [self.pose] if self.rest or not coincide else [self.pose, *self.motion()]
        # In a frame the knees part front to back in a stride; where they pass each other
        # (the nearest they come in the clip) they stand about as far apart as the hips.
        self.hip_half_gap = 0.5 * min(
            _length(pose[legs[0][part]] - pose[legs[1][part]]) for pose in poses
        )
        arms = self.alike_arms([self.map_arm(h) for h in body.hands], body.hands)
        for limbs, kind, trunk in ((legs, _LEG, body.pelvis), (arms, _ARM, body.chest)):
            for limb in limbs:
                self.check_share(limb, kind, trunk)
                for how in limb.how.values():
                    note = how[how.find(NAMES_NOT_FOLLOWED) :].rstrip(")")
                    if NAMES_NOT_FOLLOWED in how and note not in self.warnings:
                        self.warnings.append(note)
        mirrored, axis = self.assign_sides(legs, arms)
        joints = np.array([self.found[name] for name in CANONICAL_JOINTS], dtype=np.int64)
        end_sites = tuple(
            name
            for name in CANONICAL_JOINTS
            if self.how[name].startswith("end effector") or tree.skeleton.end_site[self.found[name]]
        )
        return SkeletonMap(
            joints=joints,
            family=detect_family(tree.names),
            derived=tuple(self.derived),
            end_sites=end_sites,
            head_joint=self.head_joint,
            how=self.how,
            mirrored=mirrored,
            mirror_axis=axis,
            pose=self.label,
            sides_open=self.sides_open,
            limbs_open=self.limbs_open,
            warnings=tuple(self.warnings),
        )

    def lifted_leg(self, feet: tuple[int, int], lifted: int) -> _Limb:
        """The leg ending at ``lifted`` (a foot raised off the ground) as the mirror image of
        the standing leg, joint for joint by its bones from the pelvis: the rules that find
        an ankle and a sole read a leg that comes down to the ground, and a kicked leg
        does not, while the two legs are one leg and its mirror image, bone for bone (checked
        before this reading: take._mirror_legs)."""
        tree, pelvis = self.tree, self.body.pelvis
        standing = self.map_leg(next(f for f in feet if f != lifted))
        chain = tree.chain(pelvis, lifted)[1:]
        joints: dict[str, int] = {}
        how: dict[str, str] = {}
        for part, joint in standing.joints.items():
            bones = tree.bones[joint] - tree.bones[pelvis]
            # Joints at one place (dummies) share a bone count: the same one of the group.
            group = [j for j in tree.chain(pelvis, joint)[1:] if tree.bones[j] == tree.bones[joint]]
            same = [j for j in chain if tree.bones[j] - tree.bones[pelvis] == bones]
            if not same:
                raise _NotHumanoid(
                    f"the lifted leg ending at {tree.names[lifted]!r} has no joint where the "
                    f"standing leg has its {part}"
                )
            joints[part] = same[min(len(group), len(same)) - 1]
            how[part] = f"structure: the standing leg's {part}, mirrored (the leg is lifted)"
        return _Limb(joints, how)

    def map_head(self) -> None:
        tree, body = self.tree, self.body
        chain = tree.chain(body.chest, body.head)
        named = self.named(chain[1:], "head")
        if named is not None:
            head_joint, how = named, "name"
        else:
            # The leaf itself, or its parent when the last bone is a skull-long end effector.
            leaf = body.head
            while tree.lengths[leaf] == 0 and tree.parents[leaf] != body.chest:
                leaf = int(tree.parents[leaf])
            # A leaf copying its parent bone's length beyond the head's end bone is a tool's
            # tail, no point of the body: read as if it were not there, so the head is the
            # joint below that end bone, as on the rig's source. Only where the chain above
            # the arms still holds a neck, a head joint and that end bone under the tail: a
            # person has a neck, so a shorter chain's leaf is the head itself (a neck and a
            # head bone of one length).
            above = int(tree.parents[leaf])
            if tree.tail_copy[leaf] and body.chest not in (above, int(tree.parents[above])):
                leaf = above
            parent = int(tree.parents[leaf])
            long_end = tree.lengths[leaf] >= 2 * _HEAD_END_MIN * self.extent
            # A person has a neck: a leaf *joint* (not an End Site) one joint above the arms
            # is the head on its neck, not the top of a head sitting on the shoulders.
            on_neck = tree.skeleton.end_site[leaf] or tree.parents[parent] != body.chest
            head_joint = parent if long_end and parent != body.chest and on_neck else leaf
            how = "structure: top of the spine chain"
            # The skull carries the face (eyes, jaw): where the chain to the top of the head
            # first branches above the neck is the head joint, as a named rig's "head" is.
            above_neck = chain[2 : chain.index(leaf)]
            skull = next((j for j in above_neck if len(tree.children[j]) > 1), None)
            if skull is not None:
                head_joint, how = skull, "structure: where the face branches off the head"
        self.head_joint = head_joint
        tip = self.effector(head_joint, along=body.up)
        if tip is None and head_joint != body.chest:
            # A head bowed or tilted against the spine (a frame, not a standing rest pose):
            # the top of the head continues the neck's own line.
            neck_line = self.pose[head_joint] - self.pose[int(tree.parents[head_joint])]
            tip = self.effector(head_joint, along=_unit(neck_line))
        if tip is not None:
            self.put("head", tip, "end effector beyond the head joint")
        else:
            self.put("head", head_joint, how)
        between = chain[1 : chain.index(head_joint)]
        neck = self.named(between, "neck")
        if neck is not None:
            self.put("neck", neck, "name")
        elif between:
            self.put("neck", between[0], "structure: first joint above the arms")
        else:
            self.put("neck", body.chest, "derived: the head's parent")
            self.derived.append("neck")
            self.warnings.append("neck derived from the head's parent")

    def map_spine(self) -> None:
        chain = self.tree.chain(self.body.pelvis, self.found["neck"])
        spine = next((j for j in chain[1:] if self.tree.lengths[j] > 0), self.body.chest)
        if not self.tree.is_ancestor(spine, self.body.chest):
            spine = self.body.chest
        self.put("spine", spine, "structure: first bone above the pelvis")
        self.derived.append("spine")
