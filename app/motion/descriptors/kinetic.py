"""``kinetic``: FMDistance of Onuma, Faloutsos and Hodgins (2008), made skeleton-independent.

The paper's feature is ``e_j = log(mean_t E_tj + 1)`` with ``E_tj = m_j v_tj²`` the approximate
kinetic energy of each joint DOF (constant weights ``m_j = 1``, the paper's best "61-LOG-cons"
variant) after a short linear low-pass filter, plus the root's horizontal and vertical
motion. To give every skeleton the same dimension and make the numbers independent of facing
direction, units and Euler conventions:

* the joints are the 16 rotating canonical joints (pelvis, chest, neck, head and left/right
  shoulder, elbow, wrist, hip, knee, ankle). The paper names none: its figure is the CMU
  "human figure model ... It has 29 joints, 56 joint angles" (section 4), whose hands are
  several joints. Here the wrist's DOFs are the whole hand's turn, read at the palm
  (:func:`app.motion.hand.palm`, the joint a retarget drives), never a finger's own curl,
  which a retarget keeps at rest and a rig without fingers cannot show;
* each joint's angular velocity is taken from its world rotations, never from Euler channels:
  ``ω_c = rotvec(G_c(t+1) G_c(t)ᵀ) / dt`` minus the same for its canonical parent (the pelvis
  uses its own), in rad/s; its three DOFs are its components along the pelvis-fixed body axes
  (lateral, up, forward), so a rig's rest pose and local axes do not matter;
* the short linear low-pass filter is defined in *time*: velocities are differences over a
  fixed span of 0.1 s (rounded to whole frames, divided by the span actually used), which is
  the per-frame velocity averaged by a 100 ms box filter. At 120 fps and at 30 fps this samples
  the same instants, so 30 fps and 120 fps captures of one motion agree (subsampling a
  120 fps capture otherwise folds its high-frequency jitter into the 30 fps estimate);
* the root terms are the pelvis's horizontal and vertical speed in body heights per second,
  as ``log(mean v² + 1)``.

Vector: 16 joints x 3 DOFs (``log(mean ω² + 1)``, ω in rad/s) then the two root terms: 50 numbers.
Compared with the Euclidean distance.

Still stretches and short clips are not special cases: the paper takes ``log(x + 1)`` "to
handle the joints of zero energy", so a joint (or a whole body) that does not move has the
value 0. A clip of one frame has no velocity at all and every value 0; a window whose frames
are all still has mean energy exactly 0 (the sums are exact over runs of zeros, see
:mod:`app.motion.spans`), never a rounding residue of either sign.

:func:`three_man` gives the paper's 3-MAN features (total energy, upper/lower ratio,
limbs/trunk ratio) for maps of a library.
"""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.descriptors import Descriptor, whole_clip_vector
from app.motion.kinematics import rotation_log
from app.motion.skeleton_map import CANONICAL_INDEX
from app.motion.spans import RunningMeans, whole_clip

VELOCITY_SPAN_SECONDS = 0.1

KINETIC_JOINTS: tuple[str, ...] = (
    "pelvis",
    "chest",
    "neck",
    "head",
    *(
        f"{s}_{p}"
        for s in ("l", "r")
        for p in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
    ),
)
# Whose rotation each joint's is measured against (None: the world).
KINETIC_PARENT: dict[str, str | None] = {
    "pelvis": None,
    "chest": "pelvis",
    "neck": "chest",
    "head": "neck",
    **{f"{s}_shoulder": "chest" for s in ("l", "r")},
    **{f"{s}_elbow": f"{s}_shoulder" for s in ("l", "r")},
    **{f"{s}_wrist": f"{s}_elbow" for s in ("l", "r")},
    **{f"{s}_hip": "pelvis" for s in ("l", "r")},
    **{f"{s}_knee": f"{s}_hip" for s in ("l", "r")},
    **{f"{s}_ankle": f"{s}_knee" for s in ("l", "r")},
}
# The wrist's DOFs are the hand's rotation: the hand tip's frame, which the body gives the
# palm's (build_body). Rigs split the hand over one to three joints (Hand; lwrist/lhand/
# lfingers; LeftWrist/lhand/LFingers); the palm is the one that turns the whole hand.
SEGMENT_FRAME: dict[str, str] = {f"{s}_wrist": f"{s}_hand_tip" for s in ("l", "r")}
_JOINT_INDEX = np.array([CANONICAL_INDEX[SEGMENT_FRAME.get(name, name)] for name in KINETIC_JOINTS])
_PARENT_POSITION = np.array(
    [
        -1 if KINETIC_PARENT[n] is None else KINETIC_JOINTS.index(KINETIC_PARENT[n])
        for n in KINETIC_JOINTS
    ]
)
UPPER = (
    "chest",
    "neck",
    "head",
    *(f"{s}_{p}" for s in "lr" for p in ("shoulder", "elbow", "wrist")),
)
LOWER = tuple(f"{s}_{p}" for s in "lr" for p in ("hip", "knee", "ankle"))
LIMBS = tuple(
    f"{s}_{p}" for s in "lr" for p in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
)
TRUNK = ("pelvis", "chest", "neck", "head")


def velocity_span(frame_time: float, frame_count: int) -> int:
    """Frames spanned by one velocity difference: 0.1 s, at least 1, at most the clip."""
    return int(
        min(
            max(1, int(np.floor(VELOCITY_SPAN_SECONDS / frame_time + 0.5))), max(1, frame_count - 1)
        )
    )


def body_angular_velocity(body: Body) -> np.ndarray:
    """Filtered joint angular velocities in the body frame.

    Returns
    -------
    ``(F-h, 16, 3)`` rad/s (``h`` = :func:`velocity_span`), components along (lateral, up,
    forward) of the pelvis frame, each joint relative to its canonical parent (the pelvis
    relative to the world).
    """
    rot = body.rotations[:, _JOINT_INDEX]
    span = velocity_span(body.frame_time, rot.shape[0])
    step = rot[span:] @ np.swapaxes(rot[:-span], -1, -2)
    world = rotation_log(step) / (span * body.frame_time)
    relative = world.copy()
    has_parent = _PARENT_POSITION >= 0
    relative[:, has_parent] -= world[:, _PARENT_POSITION[has_parent]]
    return relative @ body.pelvis_frames[:-span]


def root_velocity(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Pelvis velocity split into horizontal speed and vertical velocity, body heights/s.

    Returns two ``(F-h,)`` arrays, differences over :func:`velocity_span` frames.
    """
    pelvis = body.joint("pelvis") / body.height
    span = velocity_span(body.frame_time, pelvis.shape[0])
    velocity = (pelvis[span:] - pelvis[:-span]) / (span * body.frame_time)
    vertical = velocity @ body.world_up
    horizontal = np.linalg.norm(velocity - vertical[:, None] * body.world_up, axis=1)
    return horizontal, vertical


class EnergySamples:
    """Per-sample energies of one clip, ready for means over any frame span.

    Sample ``i`` is the velocity from frame ``i`` to frame ``i + span``; the samples of frame
    range ``[start, stop)`` are ``start .. stop - span``.
    """

    def __init__(self, body: Body) -> None:
        self.span = velocity_span(body.frame_time, body.frame_count)
        if body.frame_count < 2:
            joints = np.zeros((0, len(KINETIC_JOINTS) * 3))
            root = np.zeros((0, 2))
        else:
            omega = body_angular_velocity(body)
            horizontal, vertical = root_velocity(body)
            joints = (omega**2).reshape(len(omega), -1)
            root = np.stack([horizontal**2, vertical**2], axis=1)
        # Squares: never negative, and exactly 0 over a still stretch (app/motion/spans.py).
        self.joints = RunningMeans(joints)
        self.root = RunningMeans(root)

    def sample_range(self, spans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(W,)`` first and ``(W,)`` one-past-last sample of each frame span."""
        return spans[:, 0], spans[:, 1] - self.span

    def mean_energies(self, spans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(W, 16, 3)`` mean ω² per joint DOF and ``(W, 2)`` mean root speed² per span."""
        starts, stops = self.sample_range(spans)
        joints = self.joints.mean(starts, stops).reshape(len(spans), len(KINETIC_JOINTS), 3)
        return joints, self.root.mean(starts, stops)


def energy_samples(body: Body) -> EnergySamples:
    """The clip's :class:`EnergySamples`, computed once per body."""
    return body.memo("kinetic.energy_samples", lambda: EnergySamples(body))


def mean_energies(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Mean approximate kinetic energies (unit weights) over the whole clip.

    Returns
    -------
    joints:
        ``(16, 3)`` mean ω² per joint DOF, rad²/s².
    root:
        ``(2,)`` mean horizontal and vertical pelvis speed², (body heights/s)².
    """
    joints, root = energy_samples(body).mean_energies(whole_clip(body.frame_count))
    return joints[0], root[0]


def kinetic_spans(body: Body, spans: np.ndarray) -> np.ndarray:
    """``(W, 50)`` log(mean energy + 1) per joint DOF, then root horizontal and vertical."""
    return kinetic_from_energies(*energy_samples(body).mean_energies(spans))


def kinetic_from_energies(joints: np.ndarray, root: np.ndarray) -> np.ndarray:
    """``(W, 50)`` the kinetic vectors of ``(W, 16, 3)`` and ``(W, 2)`` mean energies."""
    return np.log1p(np.concatenate([joints.reshape(len(joints), -1), root], axis=1))


def three_man(body: Body) -> np.ndarray:
    """FMDistance's 3-MAN features ``(3,)``: e_all, r_upper/lower, r_limbs/trunk (paper eq. 5)."""
    joints, _ = mean_energies(body)
    return three_man_from_energies(joints.sum(axis=1)[None, :])[0]


def three_man_from_energies(per_joint: np.ndarray) -> np.ndarray:
    """3-MAN of ``(N, 16)`` mean energies per kinetic joint (DOFs summed) -> ``(N, 3)``."""
    position = {name: i for i, name in enumerate(KINETIC_JOINTS)}

    def total(names: tuple[str, ...]) -> np.ndarray:
        return np.asarray(per_joint[:, [position[n] for n in names]].sum(axis=1))

    return np.stack(
        [
            np.log(total(KINETIC_JOINTS) + 1.0),
            np.log((total(UPPER) + 1.0) / (total(LOWER) + 1.0)),
            np.log((total(LIMBS) + 1.0) / (total(TRUNK) + 1.0)),
        ],
        axis=1,
    )


def three_man_from_vectors(vectors: np.ndarray) -> np.ndarray:
    """3-MAN of stored ``(N, 50)`` kinetic vectors -> ``(N, 3)``, without the motion.

    The vector is ``log1p`` of the mean energy per joint DOF, so ``expm1`` gives the
    energies back (up to float32 rounding); negative values (a corrupt vector) count as 0.
    """
    joint_count = len(KINETIC_JOINTS)
    values = np.asarray(vectors, dtype=np.float64).reshape(len(vectors), -1)
    energies = np.expm1(np.maximum(values[:, : joint_count * 3], 0.0))
    return three_man_from_energies(energies.reshape(-1, joint_count, 3).sum(axis=2))


DESCRIPTOR = Descriptor(
    name="kinetic",
    dimension=len(KINETIC_JOINTS) * 3 + 2,
    version=3,
    description="How much each part of the body moves: the energy of every joint's rotation "
    "and of the body's travel. Finds clips of similar vigour and rhythm (a punch, a kick, a "
    "dance) whatever the pose; blind to where the limbs point.",
    compute_spans=kinetic_spans,
)
compute_kinetic = whole_clip_vector(DESCRIPTOR)
