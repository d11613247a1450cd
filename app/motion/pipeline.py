"""From a parsed :class:`Motion` to everything the service stores about a clip.

``analyse`` is the one entry point the service, the import command and the evaluation
command share: drop converter lead-in frames, map the skeleton to canonical joints, run
forward kinematics once, and compute every registered descriptor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.motion.body import Body, build_body
from app.motion.descriptors import REGISTRY
from app.motion.model import Motion


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


def analyse(motion: Motion, *, descriptors: list[str] | None = None) -> ClipAnalysis:
    """Describe one clip under every registered descriptor (or the ``descriptors`` named)."""
    body = build_body(motion)
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
    mapping = body.mapping
    if mapping is None:
        return {}
    return {
        "joints": mapping.describe(motion.skeleton.names),
        "end_sites": list(mapping.end_sites),
        "pose": mapping.pose,
        "mirrored": mapping.mirrored,
    }
