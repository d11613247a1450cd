"""From a parsed :class:`Motion` to everything the service stores about a clip.

``analyse`` is the one entry point the service, the import command and the evaluation
command share: drop converter lead-in frames, map the skeleton to canonical joints, run
forward kinematics once, and compute every registered descriptor. :func:`describable_body`
is its first half, the one verdict on whether a clip can be described at all: every route
that describes a clip (upload, import, search, moments search) goes through it, so a file
is refused by all of them or by none, whichever descriptors or windows a route computes.

Given a body that passes :func:`check_describable`, every descriptor's clip and window
vectors are finite by construction (still stretches included: see
:mod:`app.motion.spans` and the descriptors' docstrings).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from app.errors import ParseError
from app.motion.body import Body, build_body
from app.motion.descriptors import REGISTRY
from app.motion.model import Motion
from app.motion.skeleton_map import CANONICAL_INDEX, CANONICAL_JOINTS, SkeletonMap

#: Farthest (body heights) a joint may be from the pelvis, and the pelvis from where it was
#: one frame before, in a clip that is described. No capture comes near (a million body
#: heights is a country), only a sentinel or an overflowed number such as 1e30 or 1e308;
#: below it every descriptor value stays far inside float32 (posture is a squared distance,
#: at most 1e12; speeds at most 1e11 body heights per second at the fastest frame rate a
#: reader accepts).
MAX_BODY_REACH = 1e6


@dataclass(frozen=True, eq=False)
class ClipAnalysis:
    """What one clip becomes.

    Attributes
    ----------
    frame_count, frame_time, duration, joint_count:
        As read from the file (before lead-in frames are dropped); seconds for times.
    skeleton_family:
        Which naming convention the skeleton follows (e.g. ``"cmu-asf"``, ``"motionbuilder"``).
    lead_in_frames:
        Rest-pose frames a converter added at the start, dropped before describing.
    warnings:
        Short sentences about what reading and mapping had to repair or decide.
    joint_mapping:
        Which source joint became each canonical joint and how it was found (JSON-ready:
        ``{"joints": {canonical: {"joint", "how"}}, "end_sites", "pose", "mirrored"}``).
    descriptors:
        Descriptor name -> ``(D,)`` float32 vector.
    body:
        The canonical-joint view the descriptors were computed from.
    """

    frame_count: int
    frame_time: float
    duration: float
    joint_count: int
    skeleton_family: str
    lead_in_frames: int
    warnings: tuple[str, ...]
    joint_mapping: dict[str, object]
    descriptors: dict[str, np.ndarray]
    body: Body


def check_describable(body: Body, joint_names: tuple[str, ...] | None = None) -> None:
    """:class:`~app.errors.ParseError` naming the first frame that no body can take, past
    :data:`MAX_BODY_REACH` (a joint that far from the pelvis, or a pelvis that jumps that
    far). ``joint_names``: the source skeleton's names, to name the joint as the file does.
    """
    if body.frame_count == 0:
        raise ParseError("no frame is left to describe")
    pelvis = body.positions[:, CANONICAL_INDEX["pelvis"]]
    bound = (MAX_BODY_REACH * body.height) ** 2
    with np.errstate(over="ignore", invalid="ignore"):  # 1e308 - -1e308: inf, and so refused
        offsets = body.positions - pelvis[:, None]
        steps = np.diff(pelvis, axis=0)
        # squared distances (no square roots on the common path); ``not <=`` catches a NaN
        far = np.flatnonzero(~(np.einsum("fca,fca->fc", offsets, offsets) <= bound).all(axis=1))
        jumps = np.flatnonzero(~(np.einsum("fa,fa->f", steps, steps) <= bound))
    if not len(far) and not len(jumps):
        return
    with np.errstate(over="ignore", invalid="ignore"):
        reach = np.linalg.norm(offsets, axis=2) / body.height  # (F, C)
        jump = np.linalg.norm(steps, axis=1) / body.height  # (F-1,)
    first = min([*far[:1].tolist(), *(jumps[:1] + 1).tolist()])
    frame = first + body.lead_in_frames + 1
    if len(far) and far[0] == first:
        c = int(np.argmax(np.nan_to_num(reach[first], nan=np.inf)))
        joint = CANONICAL_JOINTS[c]
        if joint_names is not None and body.mapping is not None:
            source = int(body.mapping.joints[c])
            if 0 <= source < len(joint_names):
                joint = joint_names[source]
        what = f"puts joint {joint!r} {_amount(reach[first, c])} body heights from the pelvis"
    else:
        what = f"moves the pelvis {_amount(jump[first - 1])} body heights in one frame"
    raise ParseError(
        f"frame {frame} {what}: not a pose but a sentinel or overflowed number in the file; "
        "cut or repair that frame"
    )


def _amount(value: float) -> str:
    return f"{value:.3g}" if np.isfinite(value) else "more than 1e308"


def describable_body(motion: Motion) -> Body:
    """The canonical body of ``motion`` (:func:`~app.motion.body.build_body`), checked by
    :func:`check_describable`: the one verdict on whether the clip can be described.

    Raises
    ------
    ParseError
        (or SkeletonMappingError) with what is wrong.
    """
    body = build_body(motion)
    check_describable(body, motion.skeleton.names)
    return body


def analyse(
    motion: Motion, *, descriptors: list[str] | None = None, body: Body | None = None
) -> ClipAnalysis:
    """Describe one clip under every registered descriptor (or the ``descriptors`` named);
    ``body``: its :func:`describable_body`, when the caller has it already."""
    if body is None:
        body = describable_body(motion)
    names = list(REGISTRY) if descriptors is None else descriptors
    vectors = {
        name: np.ascontiguousarray(REGISTRY[name].compute(body), dtype=np.float32) for name in names
    }
    return ClipAnalysis(
        frame_count=motion.frame_count,
        frame_time=motion.frame_time,
        duration=motion.duration,
        # Joints proper: end sites are the tips of bones, not joints (MOCAP_MAX_JOINTS, a
        # bound on the arrays a file makes, counts them).
        joint_count=int(np.count_nonzero(~motion.skeleton.end_site)),
        skeleton_family=body.skeleton_family,
        lead_in_frames=body.lead_in_frames,
        warnings=body.warnings,
        joint_mapping=mapping_summary(body, motion),
        descriptors=vectors,
        body=body,
    )


def mapping_summary(body: Body, motion: Motion) -> dict[str, object]:
    """How ``motion``'s joints became ``body``'s canonical joints, as plain JSON data."""
    if body.mapping is None:
        return {}
    return mapping_json(body.mapping, motion.skeleton.names)


def mapping_json(mapping: SkeletonMap, names: Sequence[str]) -> dict[str, object]:
    """A skeleton's mapping as plain JSON data (a clip's ``joint_mapping``, a rig's)."""
    return {
        "joints": mapping.describe(names),
        "end_sites": list(mapping.end_sites),
        "pose": mapping.pose,
        "mirrored": mapping.mirrored,
    }
