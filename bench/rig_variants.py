"""Rigs from exporters we have not seen, made from the rigs we have (issue 22).

A rig is rewritten the ways exporters differ: names that say nothing, the rest pose changed
(T <-> A, soft knees and turned-out feet), bones split (twist joints) or merged, extra leaf
bones (props, eyes, helpers), units, the axes' order, a static root joint on the floor; and
all of these at once. Each rewrite works on the rig's joints by world position in its
reference pose (an exporter bakes that pose as the rest pose), so it adds, moves and drops
joints without touching anything else; :meth:`Draft.rig` makes the rig again and maps it.
``bench/eval_retarget.py generalise`` retargets clips onto every variant of every rig of
the development data; ``tests/motion/test_retarget_rigs.py`` uses a few.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.motion.ground import body_frame, snap_axis
from app.motion.kinematics import forward_kinematics
from app.motion.model import Motion, Skeleton
from app.motion.retarget import axis_change, swing
from app.motion.skeleton_map import CANONICAL_INDEX, SkeletonMap, map_skeleton


@dataclass
class Draft:
    """A rig being rewritten: joints by world position in its reference pose (``(J, 3)``,
    identity rotations: a rig whose rest pose is that pose, as an exporter bakes it), so
    joints can be added, removed and moved without touching anything else."""

    names: list[str]
    parents: list[int]
    positions: np.ndarray
    end_site: list[bool]
    unit: str

    @classmethod
    def of(cls, rig: Motion) -> Draft:
        _, positions = forward_kinematics(rig.slice_frames(0, 1))
        skeleton = rig.skeleton
        return cls(
            list(skeleton.names),
            [int(p) for p in skeleton.parents],
            positions[0].copy(),
            [bool(e) for e in skeleton.end_site],
            rig.length_unit,
        )

    def copy(self) -> Draft:
        return Draft(
            list(self.names),
            list(self.parents),
            self.positions.copy(),
            list(self.end_site),
            self.unit,
        )

    def below(self, joint: int) -> list[int]:
        """``joint`` and every joint below it."""
        out, at = [joint], 0
        while at < len(out):
            out.extend(j for j, p in enumerate(self.parents) if p == out[at])
            at += 1
        return out

    def turn(self, joint: int, rotation: np.ndarray) -> None:
        """Turn everything below ``joint`` about it by ``rotation`` ``(3, 3)``."""
        moved = self.below(joint)[1:]
        pivot = self.positions[joint]
        self.positions[moved] = (self.positions[moved] - pivot) @ rotation.T + pivot

    def add(self, name: str, parent: int, position: np.ndarray, *, end: bool = False) -> int:
        self.names.append(name)
        self.parents.append(parent)
        self.positions = np.vstack([self.positions, position])
        self.end_site.append(end)
        return len(self.names) - 1

    def remove(self, joint: int) -> None:
        """Drop ``joint``; its children hang from its parent where they are."""
        up = self.parents[joint]
        self.parents = [up if p == joint else p for p in self.parents]
        keep = [j for j in range(len(self.names)) if j != joint]
        index = {old: new for new, old in enumerate(keep)}
        self.names = [self.names[j] for j in keep]
        self.parents = [index.get(self.parents[j], -1) for j in keep]
        self.positions = self.positions[keep]
        self.end_site = [self.end_site[j] for j in keep]

    def rig(self) -> tuple[Motion, SkeletonMap]:
        """The rig (joints reordered parents first) and its mapping (raises when the mapper
        does not take it as a humanoid)."""
        order: list[int] = []
        stack = [j for j, p in enumerate(self.parents) if p < 0][::-1]
        while stack:
            j = stack.pop()
            order.append(j)
            stack.extend(c for c in reversed(range(len(self.names))) if self.parents[c] == j)
        index = {old: new for new, old in enumerate(order)}
        parents = np.array([index.get(self.parents[j], -1) for j in order], dtype=np.int64)
        positions = self.positions[order]
        offsets = np.zeros_like(positions)
        offsets[1:] = positions[1:] - positions[parents[1:]]
        skeleton = Skeleton(
            tuple(self.names[j] for j in order),
            parents,
            offsets,
            np.array([self.end_site[j] for j in order], dtype=bool),
        )
        count = len(order)
        rig = Motion(
            skeleton=skeleton,
            frame_time=1 / 30,
            root_translation=positions[None, 0].copy(),
            local_rotations=np.broadcast_to(np.eye(3), (1, count, 3, 3)).copy(),
            length_unit=self.unit,
        )
        return rig, map_skeleton(skeleton, poses=[("frame 0", positions)])


def _joint(mapping: SkeletonMap, name: str) -> int:
    return int(mapping.joints[CANONICAL_INDEX[name]])


def _axes(draft: Draft, mapping: SkeletonMap) -> np.ndarray:
    """``(3, 3)`` body axes (columns lateral to the left, up, forward) of the draft's pose."""
    return body_frame(draft.positions[mapping.joints])


def _towards(direction: np.ndarray, other: np.ndarray, degrees: float) -> np.ndarray:
    """``(3, 3)`` rotation turning ``direction`` by ``degrees`` towards ``other``."""
    d = direction / np.linalg.norm(direction)
    o = other - (other @ d) * d
    o = o / np.linalg.norm(o)
    angle = np.radians(degrees)
    return swing(d, np.cos(angle) * d + np.sin(angle) * o)


def _renamed(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # Names that say nothing (an exporter's bone ids): the mapper reads the structure.
    draft.names = [f"bone{j:03d}" for j in range(len(draft.names))]


def _arms_t_a(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # A T-pose rig becomes an A-pose one (arms 45 deg down) and an A-pose one a T-pose one.
    axes = _axes(draft, mapping)
    up = axes[:, 1]
    for side in ("l", "r"):
        shoulder, elbow = _joint(mapping, f"{side}_shoulder"), _joint(mapping, f"{side}_elbow")
        arm = draft.positions[elbow] - draft.positions[shoulder]
        elevation = np.degrees(np.arcsin(np.clip(arm @ up / np.linalg.norm(arm), -1, 1)))
        flat = arm - (arm @ up) * up
        wanted = -45.0 if elevation > -25.0 else 0.0
        draft.turn(shoulder, _towards(flat, up, wanted) @ swing(arm, flat))


def _bent_rest(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # A rest pose with soft knees (thighs 15 deg forward, shins 15 deg back) and feet turned
    # out by 15 deg, as a rig skinned in a relaxed stance.
    axes = _axes(draft, mapping)
    lateral, forward = axes[:, 0], axes[:, 2]
    for side, outward in (("l", lateral), ("r", -lateral)):
        hip, knee = _joint(mapping, f"{side}_hip"), _joint(mapping, f"{side}_knee")
        ankle = _joint(mapping, f"{side}_ankle")
        thigh = draft.positions[knee] - draft.positions[hip]
        draft.turn(hip, _towards(thigh, forward, 15.0))
        shin = draft.positions[ankle] - draft.positions[knee]
        draft.turn(knee, _towards(shin, -forward, 30.0))
        draft.turn(ankle, _towards(forward, outward, 15.0))


def _split(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # Twist joints: each limb bone (and the spine's lowest) split in two at a random point.
    pairs = [("pelvis", "spine")] + [
        (f"{s}_{a}", f"{s}_{b}")
        for s in ("l", "r")
        for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle"))
    ]
    for top, end in pairs:
        a, b = _joint(mapping, top), _joint(mapping, end)
        if b not in draft.below(a)[1:]:
            continue  # a foot held under the root, a spine point derived at the pelvis
        up = draft.parents[b]
        at = draft.positions[up] + rng.uniform(0.25, 0.75) * (
            draft.positions[b] - draft.positions[up]
        )
        draft.parents[b] = draft.add(f"{draft.names[up]}_part", up, at)


def _merged(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # A rig with fewer bones: every other joint between the pelvis and the neck, and any
    # unmapped joint inside a limb (twist bones), merged into its parent bone.
    pelvis, neck = _joint(mapping, "pelvis"), _joint(mapping, "neck")
    spine, j = [], draft.parents[neck]
    while j >= 0 and j != pelvis:
        spine.append(j)
        j = draft.parents[j]
    mapped = {int(m) for m in mapping.joints} | {mapping.head_joint}
    drop = set(spine[::2]) if j == pelvis and len(spine) > 1 else set()
    for s in ("l", "r"):
        for top, end in (
            ("shoulder", "elbow"),
            ("elbow", "wrist"),
            ("hip", "knee"),
            ("knee", "ankle"),
        ):
            a, k = _joint(mapping, f"{s}_{top}"), draft.parents[_joint(mapping, f"{s}_{end}")]
            while k >= 0 and k != a:
                if k not in mapped:
                    drop.add(k)
                k = draft.parents[k]
    for joint in sorted(drop, reverse=True):
        draft.remove(joint)


def _leaves(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # Helper bones an exporter adds as leaves: a control at the pelvis, eyes, a prop on each
    # hand, knee caps, a twist helper at each elbow.
    axes = _axes(draft, mapping)
    forward = axes[:, 2]
    height = float(np.ptp(draft.positions @ axes[:, 1]))
    at = draft.positions
    head = mapping.head_joint if mapping.head_joint >= 0 else _joint(mapping, "head")
    draft.add("ctrl", _joint(mapping, "pelvis"), at[_joint(mapping, "pelvis")].copy())
    for side in ("l", "r"):
        draft.add(f"eye_{side}", head, at[head] + 0.05 * height * forward)
        draft.add(
            f"prop_{side}",
            _joint(mapping, f"{side}_wrist"),
            at[_joint(mapping, f"{side}_wrist")] + 0.04 * height * forward,
        )
        draft.add(
            f"kneecap_{side}",
            _joint(mapping, f"{side}_knee"),
            at[_joint(mapping, f"{side}_knee")] + 0.03 * height * forward,
        )
        draft.add(
            f"elbow_helper_{side}",
            _joint(mapping, f"{side}_elbow"),
            at[_joint(mapping, f"{side}_elbow")].copy(),
        )


def _units(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # Metres to centimetres, or anything larger to metres.
    height = float(np.ptp(draft.positions, axis=0).max())
    scale = 100.0 if height < 10.0 else 0.01
    draft.positions = draft.positions * scale
    draft.unit = "cm" if scale > 1 else "m"


def _z_up(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # Another axes order: the body's up becomes the next coordinate axis (Y-up -> Z-up).
    up = snap_axis(_axes(draft, mapping)[:, 1])
    turn = axis_change(up, np.roll(np.abs(up), 1))
    draft.positions = draft.positions @ turn.T


def _top_root(draft: Draft, mapping: SkeletonMap, rng: np.random.Generator) -> None:
    # A static root joint on the floor under the pelvis, as game rigs have.
    up = snap_axis(_axes(draft, mapping)[:, 1])
    pelvis = draft.positions[_joint(mapping, "pelvis")]
    floor = float((draft.positions @ up).min())
    at = pelvis - (pelvis @ up - floor) * up
    top = [j for j, p in enumerate(draft.parents) if p < 0]
    new = draft.add("root", -1, at)
    for j in top:
        draft.parents[j] = new


Rewrite = Callable[[Draft, SkeletonMap, np.random.Generator], None]
VARIANTS: dict[str, tuple[Rewrite, ...]] = {
    "renamed": (_renamed,),
    "T <-> A rest": (_arms_t_a,),
    "bent rest": (_bent_rest,),
    "split bones": (_split,),
    "merged bones": (_merged,),
    "extra leaves": (_leaves,),
    "units": (_units,),
    "axes (Z-up)": (_z_up,),
    "static top root": (_top_root,),
    "all at once": (_split, _leaves, _arms_t_a, _renamed, _units, _z_up),
}


def unseen_variants(rig: Motion, mapping: SkeletonMap, seed: int = 0) -> list[tuple[str, Draft]]:
    """The rig rewritten as rigs of exporters we have not seen, one per :data:`VARIANTS`
    kind (seeded: the same rig gives the same variants)."""
    rng = np.random.default_rng(seed)
    base = Draft.of(rig)
    out = []
    for kind, rewrites in VARIANTS.items():
        draft = base.copy()
        for rewrite in rewrites:
            # Each step reads the geometry it rewrites through the mapping of the draft
            # before it (joint indices stay valid: steps only append joints, or run last).
            rewrite(draft, mapping, rng)
        out.append((kind, draft))
    return out


__all__ = ["VARIANTS", "Draft", "unseen_variants"]
