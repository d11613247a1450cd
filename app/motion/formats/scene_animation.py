"""A scene file's animations (FBX, glTF): which one is read, what the clip says about it,
and the errors of a file that has no skeleton or no motion.

Shared by both scene readers; the node graph itself is :mod:`app.motion.formats.scene`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from app.errors import (
    LimitExceeded,
    NoAnimation,
    ParseError,
    SkeletonMappingError,
    UnknownAnimation,
)
from app.motion.model import ParseLimits


@dataclass(frozen=True)
class Animation:
    """One animation of a file: its name, length in frames at the sampling rate, the
    seconds those frames cover (``frame_count / rate``: a clip's ``duration`` counts so),
    and whether it moves any node at all (the FBX SDK writes an empty ``Take 001`` beside a
    Mixamo take, longer than it: a span of time that animates nothing). ``parts``: the
    animations it joins, when it is one take the file wrote split over several
    (:mod:`app.motion.formats.split_takes`); each is also listed by itself."""

    name: str
    frame_count: int
    duration: float
    moves: bool = True
    parts: tuple[str, ...] = ()  # a take written split over these animations, joined


def rig_without_animation(joints: int, why: str) -> NoAnimation:
    """The error for a file whose skeleton of ``joints`` joints has no motion (``why``)."""
    return NoAnimation(
        f"the file is a rig with no animation: a skeleton of {joints} joints and {why}, so "
        "there is no motion to describe"
    )


def no_skeleton(animations: list[Animation], what: str) -> ParseError:
    """The error for a file with no skeleton (``what`` says what was looked for). When nothing
    in it moves either (no animation, or only single instants) it is a static model — a prop,
    a mesh without bones — which is not a person to map (:class:`SkeletonMappingError`), and
    the message says there is no animation as well; it is not a rig (no bones to drive)."""
    if all(a.frame_count <= 1 for a in animations):
        # An animation of no keyframes over time is said by name: an exporter that could
        # not bind its tracks (three.js's GLTFExporter drops those of "mixamorig:" names)
        # writes one, and "no animation" would hide that the file meant to hold one.
        moves = "no animation"
        if animations:
            shown = ", ".join(repr(a.name) for a in animations[:5])
            more = " ..." if len(animations) > 5 else ""
            moves = f"no animation (its animations {shown}{more} hold no keyframes over time)"
        return SkeletonMappingError(
            f"not a whole humanoid: the file has no skeleton ({what}) and {moves}: a static "
            "model, nothing moves"
        )
    return ParseError(f"the file has no skeleton ({what})")


def pick_animation(animations: list[Animation], name: str | None, *, joints: int = 0) -> int:
    """Index of the animation called ``name``, else of the longest that moves a node (first
    of equals; the longest of all when none moves).

    A file without animations is a rig with no animation (:class:`NoAnimation`; ``joints``
    is the skeleton's size, for the message). A zero-length animation (one instant: a pose
    written as a take) is read as a one-frame still: the file says that pose is its motion,
    and :func:`scene_notes` says so in the clip's warnings."""
    if not animations:
        raise rig_without_animation(joints, "no animation")
    if name is None:
        moving = [i for i, a in enumerate(animations) if a.moves] or range(len(animations))
        longest = max(animations[i].frame_count for i in moving)
        chosen = next(i for i in moving if animations[i].frame_count == longest)
    else:
        found = [i for i, animation in enumerate(animations) if animation.name == name]
        if not found:
            listed = ", ".join(repr(a.name) for a in animations[:50])
            raise UnknownAnimation(
                f"animation: the file has no animation {name!r}; it has {listed}"
            )
        chosen = found[0]
    return chosen


def choice_warnings(animations: list[Animation], chosen: int, name: str | None) -> list[str]:
    """What a file of several animations read without a name says: which one was read and
    why (see :func:`pick_animation`)."""
    if name is not None or len(animations) < 2:
        return []
    read = animations[chosen]
    passed = [a.name for a in animations if not a.moves and a.frame_count > read.frame_count]
    why = "the longest that moves a node" if passed else "the longest"
    warning = (
        f"the file holds {len(animations)} animations: {read.name!r}, {why}, is read; name "
        "another in the 'animation' field to read it"
    )
    if passed:
        shown = ", ".join(repr(n) for n in passed[:5]) + (" ..." if len(passed) > 5 else "")
        warning += f" (longer, but moving nothing: {shown})"
    if read.parts:
        warning += (
            f"; it joins {len(read.parts)} animations of one span that each move their own part "
            "of the skeleton (one take written split, one per animated object)"
        )
    return [warning]


def scene_notes(animation: Animation, warnings: Sequence[str] = ()) -> dict[str, object]:
    """The notes of a motion read from ``animation``: its name, and its warnings: a reader's
    own (``warnings``), and one when it is a single instant (stored as a one-frame still
    rather than refused as a rig)."""
    notes: dict[str, object] = {"animation": animation.name}
    said = list(warnings)
    if animation.frame_count <= 1:
        said.insert(
            0, f"the animation {animation.name!r} is a single instant: stored as a one-frame still"
        )
    if said:
        notes["warnings"] = said
    return notes


def check_frame_budget(limits: ParseLimits, frames: int, nodes: int) -> None:
    """LimitExceeded when ``frames`` frames of the skeleton's ``nodes`` kept nodes (its joints
    and their ancestors, :func:`skeleton_nodes`: what is sampled and kept) are too many.

    Counted as a BVH's joints are: nine numbers per node and frame, the rotations the clip
    becomes in the server. The sampling itself runs in a parser worker, bounded by that
    worker's own memory limit (MOCAP_PARSER_MEMORY_MB)."""
    if frames < 1:
        raise ParseError("the animation has no frames")
    problem = limits.frame_budget_problem(frames, 0, nodes)
    if problem is not None:
        raise LimitExceeded(problem)
