"""Which target joints a retarget drives, and from which source joints.

One driven target joint per canonical bone both skeletons have (pelvis, spine, chest, neck,
head, clavicles, upper arms, forearms, hands, thighs, shins, feet, toes), paired through the
structural mapping (:mod:`app.motion.skeleton_map`), with the joints each bone aims at so
its direction can be made the source's. Where both skeletons have as many joints between two
canonical joints (a spine of three against three, a limb bone split by twist joints at other
points) those are paired one by one too. The head joint and the hand's palm are driven
without a direction (their own direction depends on what lies beyond them); the palm is
:func:`app.motion.hand.palm`, the joint the descriptors read the hand at.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from app.motion.hand import between, palm
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap

# Canonical chains whose joints the retarget drives, top first: (base, end) canonical names.
# Joints between the two are driven too when both skeletons have as many there (a spine of
# three against three); ``None``: the base's rotation is transferred, its direction not
# corrected (the pelvis, whose children go three ways; the hand, whose direction depends on
# the fingers, which stay at rest).
_CHAINS: tuple[tuple[str, str | None], ...] = (
    ("pelvis", None),
    ("pelvis", "spine"),
    ("spine", "chest"),
    ("chest", "neck"),
    ("neck", "head"),
    *(
        pair
        for side in ("l", "r")
        for pair in (
            ("chest", f"{side}_shoulder"),
            (f"{side}_shoulder", f"{side}_elbow"),
            (f"{side}_elbow", f"{side}_wrist"),
            (f"{side}_wrist", None),
            ("pelvis", f"{side}_hip"),
            (f"{side}_hip", f"{side}_knee"),
            (f"{side}_knee", f"{side}_ankle"),
            (f"{side}_ankle", f"{side}_toe"),
        )
    ),
)
# The limbs' long bones: one rigid bone in the body however many pieces a rig splits it
# into (twist joints), so it turns as one (:func:`app.motion.retarget_transfer.turn_split_limbs`).
# The spine's pieces are a chain that bends by design and keep their own directions.
_LIMB_BONES = frozenset(
    (f"{side}_{top}", f"{side}_{end}")
    for side in ("l", "r")
    for top, end in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))
)


# The pelvis's own bones to the hip joints: one rigid bone in the body (the pelvis), which
# rigs split at places of their own (a hip bone from the pelvis's centre, a buttock joint at
# the hip's side). Their joints turn as the source's do, but are not aimed: aimed, a rig's
# hip bone took the direction of another segment (both hips down and back from the pelvis's
# centre, the hip joints brought together).
_GIRDLE = frozenset(("pelvis", f"{side}_hip") for side in ("l", "r"))


@dataclass(frozen=True)
class Driven:
    """One driven target joint and where its rotation comes from."""

    target: int
    source: int
    target_aim: int | None  # target joint the bone points at (None: no direction fix)
    source_aim: int | None
    align_like: int | None = None  # target joint whose reference alignment this one shares
    # Bones (target from, to, source from, to) aligned in the reference poses, for a joint
    # whose direction is not fixed per frame (the head: its up onto the source head's up).
    align_bones: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class Limb:
    """A limb bone both skeletons split into as many pieces (twist joints), whose
    pieces are driven one by one: ``pieces`` the target joints from the bone's base, down to
    the target joint ``end``; ``source_base`` -> ``source_end`` the source's bone."""

    pieces: tuple[int, ...]
    end: int
    source_base: int
    source_end: int


def driven_joints(
    source: Motion, source_map: SkeletonMap, target: Motion, target_map: SkeletonMap
) -> tuple[list[Driven], list[Limb]]:
    """The driven target joints, each with its source joint and the joints they aim at (see
    :data:`_CHAINS`); the head joint is a chain end of its own where the head point is an end
    effector beyond it. Target-first wins: a joint is driven by the first chain naming it.
    Also the limb bones both split into as many pieces, driven piece by piece."""
    s_parents, t_parents = source.skeleton.parents, target.skeleton.parents
    out: list[Driven] = []
    limbs: list[Limb] = []
    seen: set[int] = set()

    def add(t: int, s: int, t_aim: int | None, s_aim: int | None, like: int | None) -> None:
        if t in seen or target.skeleton.end_site[t] or source.skeleton.end_site[s]:
            return
        if t_aim is not None and (t_aim == t or s_aim == s or s_aim is None):
            t_aim = s_aim = None
        seen.add(t)
        out.append(Driven(t, s, t_aim, s_aim, like))

    def joints(mapping: SkeletonMap, name: str) -> list[int]:
        """The canonical joint ``name`` as one or two joints (neck -> head joint -> head)."""
        j = int(mapping.joints[CANONICAL_INDEX[name]])
        if name == "head" and 0 <= mapping.head_joint != j:
            return [mapping.head_joint, j]
        return [j]

    for base, end in _CHAINS:
        t_base, s_base = joints(target_map, base)[-1], joints(source_map, base)[-1]
        if end is None:
            # The hand turns with the forearm's alignment: its own direction depends on
            # how the fingers are held, which differs between any two reference poses.
            like = None
            if base.endswith("_wrist"):
                like = int(target_map.joints[CANONICAL_INDEX[base.replace("wrist", "elbow")]])
                # The palm (where the fingers branch) carries the hand's orientation; a rig
                # may turn the hand there rather than at the wrist (wrist -> hand -> fingers).
                tip = CANONICAL_INDEX[base.replace("wrist", "hand_tip")]
                add(
                    palm(target.skeleton, t_base, int(target_map.joints[tip])),
                    palm(source.skeleton, s_base, int(source_map.joints[tip])),
                    None,
                    None,
                    like,
                )
            add(t_base, s_base, None, None, like)
            continue
        t_stops, s_stops = [t_base, *joints(target_map, end)], [s_base, *joints(source_map, end)]
        if len(t_stops) != len(s_stops):
            # One has a head joint with an end effector beyond it, the other a head joint
            # only: the joints pair up (the neck aims at the head joint).
            t_stops, s_stops = t_stops[:2], s_stops[:2]
        t_path, s_path = [t_stops[0]], [s_stops[0]]
        for i in range(1, len(t_stops)):
            t_mid = between(t_parents, t_stops[i - 1], t_stops[i])[::-1]
            s_mid = between(s_parents, s_stops[i - 1], s_stops[i])[::-1]
            if t_mid and len(t_mid) == len(s_mid):
                if (base, end) in _LIMB_BONES:
                    limbs.append(
                        Limb((t_stops[i - 1], *t_mid), t_stops[i], s_stops[i - 1], s_stops[i])
                    )
                t_path.extend(t_mid)
                s_path.extend(s_mid)
            t_path.append(t_stops[i])
            s_path.append(s_stops[i])
        for i in range(len(t_path) - 1):
            if (base, end) in _GIRDLE and i > 0:
                add(t_path[i], s_path[i], None, None, None)
            else:
                add(t_path[i], s_path[i], t_path[i + 1], s_path[i + 1], None)
    # The head joint turns as the other's head joint does (a chain's end is only aimed at,
    # and a head joint with no end effector beyond it ends the chain): it carries the face,
    # whatever points lie beyond it. Its reference alignment takes its up (head joint -> top
    # of the head, or neck -> head where nothing lies beyond) onto the source head's up.
    t_head, s_head = joints(target_map, "head"), joints(source_map, "head")
    t_neck = int(target_map.joints[CANONICAL_INDEX["neck"]])
    s_neck = int(source_map.joints[CANONICAL_INDEX["neck"]])
    t_up = (t_head[0], t_head[1]) if len(t_head) > 1 else (t_neck, t_head[0])
    s_up = (s_head[0], s_head[1]) if len(s_head) > 1 else (s_neck, s_head[0])
    before = len(out)
    add(t_head[0], s_head[0], None, None, t_neck)
    if len(out) > before:
        out[-1] = replace(out[-1], align_bones=(*t_up, *s_up))
    return out, limbs


__all__ = ["Driven", "Limb", "between", "driven_joints", "palm"]
