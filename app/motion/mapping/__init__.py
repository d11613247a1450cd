"""Source skeleton -> the canonical joints every descriptor uses, by the body's structure.

A humanoid is a tree with a pelvis from which two legs go down and a spine goes up to the
head, with two arms branching off the upper spine. That shape is visible in a standing pose
(the rest pose of the offsets, or a frame of the motion when the rest pose is not a standing
figure, as in rigs that bake joint orientation into rotations) whatever the up axis, units,
facing, naming or extra joints (fingers, face, twist bones, props, IK targets, dummies).

0. **Points, not joints.** Leaves that add no point (zero-length End Sites, which a BVH
   writer appends to every leaf joint of an FBX or glTF rig) are not seen at all; nor is an
   End Site exactly as long as its bone (a tail Blender invents for a leaf joint), nor a
   bone hung along a sibling bone's line short of its end, with what hangs below it on that
   line or as its End Site (twist helpers, a sleeve: :mod:`.along`).
1. **Extremities.** Leaves at least two bones below the root (thigh and shin, upper arm and
   forearm: a hip may sit at the pelvis itself) and far apart along bones are found
   greedily (the farthest leaf from the ones already chosen, up to :data:`_CANDIDATES`);
   every choice of five of them as head,
   two hands and two feet is checked: the arms' branch point (chest) must carry the head
   and not the feet, the feet must lie well below the pelvis (the branch point of legs and
   spine) along the pelvis->chest direction, and the legs must point opposite the spine
   (a horizontal spine over four limbs is a quadruped). The cheapest valid choice wins;
   costs are left/right chain-length differences and names that contradict a role (an arm
   chain whose joints are called leg names).
2. **Chains.** Along each limb chain: the ankle is where the chain turns forward (the
   rest of the chain drops little for its length; or the joint above that turn when a foot
   pointing down turns only at the ball and the leg's proportions say so clearly; a leaf
   turning back up from a foot coming down is no toe), else named, else the one of the
   leg's last joints nearest human proportions (a foot that points down); the hip and shoulder
   start the straight run ending at the ankle or wrist (or the joint above it when the run
   leaves no room for a middle joint, or the joint at the trunk's own place when hips sit at
   the pelvis; a leg's run goes on up through a bone turning forward or back but not outward,
   and an arm's run lying farther from the spine's line than it is long is the forearm alone,
   its top the elbow); the knee and elbow split that run (a rest-pose bend decides when there
   is one, for a knee only between comparable parts, otherwise the split nearest human
   proportions); the wrist is named, or else, among
   where the fingers branch (a joint with several, or sibling palm joints at one place; when
   nothing branches, the highest joint whose reach is no longer than a bone above it), the
   two joints before the hand's end and the arm's last joint (a rig without hand bones), the
   one whose upper arm, forearm and hand come nearest human proportions (where the fingers
   branch standing unless another is clearly nearer, and never a wrist whose arm would not
   make its share of the way from the chest, nor one whose shoulder is at the chest's own
   place, or is the arm's first joint below the chest and lies nearer the spine's line than
   a hip joint — or, where the hips sit at the pelvis, a knee: that is a collar's root; a
   joint lower down hangs from the collar, whatever the hips' gap; a hand shorter than a
   person's on an arm where nothing branches, a hand drawn in part, costs no more than no
   hand); the ankle likewise
   when the foot does not turn forward (and when the turn is a knee's: on a leg with no foot
   bones a knee bent with the shin more level than an upright thigh turns as an ankle does,
   and read so it leaves the two legs one hip); two legs never share their hip, and each limb makes
   most of the way from the trunk to its end (a creature's claws hanging at the end of its
   legs are no person's legs). A game rig whose feet are IK bones under the root (legs
   ending at the knees) is mapped, when nothing else maps, with each foot hung from the knee
   it stays at one distance from while the knee bends (:attr:`SkeletonMap.held`). Names
   whole-matched by :mod:`app.motion.skeleton_names` choose among joints when they name one
   in the chain, unless the limb they name is no person's (its forearm or shin less than
   half a person's share for its upper part: names shifted one joint down the limb) and the
   geometry finds one; a warning then says the names were not followed. Where the rest pose
   leaves joints in one line to choose among (a collar bone in line with a T-posed arm,
   whose long forearm makes the proportions prefer it; a wrist among a straight hand's
   joints), the clip's frames decide: a bone does not bend, so a joint that turns inside the
   upper or lower part of the chosen limb is a joint of the limb (the shoulder below the
   collar, the wrist above a finger), and the nearest to proportions of the choices with no
   such joint is taken
   (:attr:`SkeletonMap.limbs_open`).
3. **End effectors** (Miura et al.: "end effectors are hereafter regarded as joints"): the
   canonical ``head`` point is the first point of non-zero length on the single chain
   beyond the head joint (an End Site, or a ``HeadTop``-like leaf bone: a BVH converted
   from FBX appends an End Site after that bone, and both files then map the same point)
   when there is one, else the head joint (a leaf *joint* one joint above the arms is
   the head on its neck, not the top of a head sitting on the shoulders: a person has a
   neck); ``toe`` likewise beyond the toe joint (else the toe joint, else the farthest
   point beyond the ankle); a foot whose toe points back against the shin's front where
   the knee bends (a heel bone beside the foot) ends instead at a foot-long leaf beside it
   pointing forward, or, short as a heel with none, at the ankle; ``hand_tip`` is the farthest point
   beyond the wrist, thumbs skipped (the wrist itself on a rig without hand bones).
   :attr:`SkeletonMap.head_joint` keeps the head *joint* for body height.
4. **Sides.** Left is where bent knees' hinge axes (thigh x shin) point, else ``up x
   forward`` (forward from the feet, else the knees' bend). Names saying left/right on both
   limb pairs decide which is which; when both pairs disagree with the geometry, the capture
   is mirrored (:attr:`SkeletonMap.mirrored`: the caller reflects the motion); when only one
   pair disagrees, geometry wins with a warning. Rigs without side names get sides from
   geometry alone. When the mapping comes from frames (no standing rest pose), the sides are
   read from the hips and shoulders only (knees and hands cross in a side step or a slash)
   and several frames vote, so every clip of a rig — and every part of a clip, cut out and
   searched with — gets the same sides. A standing rest pose that shows no side (straight
   knees, no feet), or shows it by bent knees (a person at rest stands on straight knees:
   such a rest pose is a pose of the take), lets the clip's frames vote likewise
   (:attr:`SkeletonMap.sides_open`).

When neither the rest pose nor any frame offered shows a standing figure (a seated, crouched
or lying take, a pose estimator's first frame taken for rest), the take is read once more as
a person bent at the hips and knees: lower legs going down the trunk, mirror-image legs, and
the world's up (the coordinate axis along which both feet rest) showing the trunk upright or
lying, not a spine level over hanging legs (:mod:`.take`); last, as a person standing on one
leg with the other foot lifted (a single pose of a kick or a fighting stance: the legs
opposite the spine as standing, mirror-image legs, arms shorter than the legs, the lifted
leg mapped as the standing one's mirror image). Such a mapping carries a warning.

What the tree alone decides (the candidate limb ends, the choices it allows) and, when the
rest pose shows a standing figure, the whole mapping are kept per skeleton: every clip of a
rig after the first is mapped without redoing them.

Whatever is not a whole humanoid (quadruped, hand, face, upper body only, all-zero offsets)
is refused with :class:`~app.errors.SkeletonMappingError` saying what was found and what is
missing.

Modules, by responsibility: :mod:`.canonical` (the canonical joints, :class:`SkeletonMap`),
:mod:`.tree` (the skeleton's tree, candidate limb ends), :mod:`.along` (bones hung along
another: not seen), :mod:`.hypotheses` (head, hands and
feet: step 1), :mod:`.state`, :mod:`.runs` (a limb's straight runs),
:mod:`.named` (names along a limb weighed against its proportions), :mod:`.feet` (a heel
beside the foot), :mod:`.limbs` (legs,
and what arms share with them), :mod:`.arms` and :mod:`.sides` (steps 2-4 for one
hypothesis),
:mod:`.mapper` (one pose's mapping), :mod:`.held` (limb ends held by IK), :mod:`.take` (a
take that never stands) and :mod:`.skeleton`
(:func:`map_skeleton`: rest pose, then frames, kept per skeleton). Callers import the public
names from :mod:`app.motion.skeleton_map`.
"""
