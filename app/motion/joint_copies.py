"""A joint's turn written once per child, folded back onto the joint.

Some writers give a joint no turn of its own and put it on each of its children instead,
every child at the joint's own place (no offset, no translation) and turning alike in every
frame: Notch's ``Root`` never turns while ``Hip`` (the spine's start), ``LeftHip`` and
``RightHip`` all sit on it and carry the pelvis's turn, three copies of one rotation. The
mapper takes the joint the legs and the spine part from as the pelvis, which then holds still
in every frame: the body's frame never turned or leant, and the energy of the pelvis's turn
was nowhere.

:func:`folded_copies` moves such a shared turn onto the joint (its local rotation times the
children's, theirs the identity). Every world position is unchanged (the children sit at the
joint's place, and their world rotations are the same product); only the joint's own frame
turns, as the body's pelvis does.

Shapes: local rotations ``(F, J, 3, 3)``; offsets ``(J, 3)``; local translations ``(F, J, 3)``.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from app.motion.model import Motion

# Rotations equal to this (what one number written twice parses to, give or take rounding in
# a converter's own arithmetic) are one turn.
_SAME_TURN = 1e-9


def folded_copies(motion: Motion) -> Motion:
    """``motion`` with every joint whose two or more children all sit at its place and turn
    alike in every frame given that turn itself (see the module docstring); ``motion``
    itself when there is none."""
    skeleton = motion.skeleton
    parents = skeleton.parents
    extent = float(np.abs(skeleton.offsets).max(initial=0.0))
    rotations = motion.local_rotations
    changed: np.ndarray | None = None
    # Parents come before their children: a fold above is done before the joints below it
    # are asked. Only joints of two or more children can hold copies (a clip's hot path: one
    # look at the tree, not one per joint).
    counts = np.bincount(parents[parents >= 0], minlength=skeleton.joint_count)
    for joint in np.flatnonzero(counts >= 2):
        children = np.flatnonzero(parents == joint)
        if not _at_the_joint(motion, children, extent):
            continue
        source = rotations if changed is None else changed
        first = source[:, children[0]]  # (F, 3, 3)
        if np.allclose(first, np.eye(3), rtol=0.0, atol=_SAME_TURN):
            continue  # nothing turns there
        if not all(
            np.allclose(source[:, c], first, rtol=0.0, atol=_SAME_TURN) for c in children[1:]
        ):
            continue
        if changed is None:
            changed = rotations.copy()
        changed[:, joint] = changed[:, joint] @ first
        changed[:, children] = np.eye(3)
    if changed is None:
        return motion
    return dataclasses.replace(motion, local_rotations=changed)


def _at_the_joint(motion: Motion, children: np.ndarray, extent: float) -> bool:
    """Whether every one of ``children`` sits at its parent's place, at rest and, where the
    clip has per-joint translations, in every frame."""
    near = 1e-9 * max(extent, 1e-300)
    if np.abs(motion.skeleton.offsets[children]).max() > near:
        return False
    translations = motion.local_translations
    return translations is None or bool(np.abs(translations[:, children]).max() <= near)
