"""Checks every human clip's canonical skeleton must pass, whatever format it came from."""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.skeleton_map import CANONICAL_INDEX

LIMBS = (("hip", "knee"), ("knee", "ankle"), ("shoulder", "elbow"), ("elbow", "wrist"))


def _joint(body: Body, name: str) -> np.ndarray:
    return body.positions[:, CANONICAL_INDEX[name]]


def check_canonical_body(body: Body, what: str) -> None:
    """Upright (head over pelvis over ankles along the world's up), constant limb lengths,
    left joints on the left (the toes point forward of left x up), human proportions."""
    up = body.world_up
    height = body.height
    head, pelvis = _joint(body, "head") @ up, _joint(body, "pelvis") @ up
    ankles = (_joint(body, "l_ankle") @ up + _joint(body, "r_ankle") @ up) / 2
    standing = np.median(head - ankles)
    assert np.median(head - pelvis) > 0.15 * height, (what, "head not above the pelvis")
    assert standing > 0.3 * height, (what, "not upright", standing / height)
    for side in ("l", "r"):
        for a, b in LIMBS:
            length = np.linalg.norm(
                _joint(body, f"{side}_{a}") - _joint(body, f"{side}_{b}"), axis=-1
            )
            assert length.mean() > 0.05 * height, (what, side, a, b, "limb too short")
            assert length.std() <= 1e-3 * length.mean(), (what, side, a, b, "length varies")
    # Sides: the body's lateral axis (right hip -> left hip) crossed with up is forward; the
    # feet point that way (toes ahead of ankles) in most frames.
    lateral = _joint(body, "l_hip") - _joint(body, "r_hip")
    forward = np.cross(lateral, up)
    toes = [
        ((_joint(body, f"{s}_toe") - _joint(body, f"{s}_ankle")) * forward).sum(axis=-1)
        for s in ("l", "r")
    ]
    toes_known = [t[np.isfinite(t)] for t in toes]
    if all(t.size for t in toes_known) and np.median(np.concatenate(toes_known)) <= 0:
        # A crude rig's toe joint under the ankle pitches back as the foot rolls: then
        # the knees, which bend forward, must do so in most frames.
        knees = np.concatenate(
            [
                (
                    (
                        _joint(body, f"{s}_knee")
                        - (_joint(body, f"{s}_hip") + _joint(body, f"{s}_ankle")) / 2
                    )
                    * forward
                ).sum(axis=-1)
                for s in ("l", "r")
            ]
        )
        assert np.mean(knees > 0) >= 0.75, (what, "left and right swapped")
    # Proportions, relative to the body height.
    leg = np.linalg.norm(_joint(body, "l_hip") - _joint(body, "l_knee"), axis=-1).mean()
    leg += np.linalg.norm(_joint(body, "l_knee") - _joint(body, "l_ankle"), axis=-1).mean()
    arm = np.linalg.norm(_joint(body, "l_shoulder") - _joint(body, "l_elbow"), axis=-1).mean()
    arm += np.linalg.norm(_joint(body, "l_elbow") - _joint(body, "l_wrist"), axis=-1).mean()
    shoulders = np.linalg.norm(_joint(body, "l_shoulder") - _joint(body, "r_shoulder"), axis=-1)
    assert 0.3 < leg / height < 0.7, (what, "leg / height", leg / height)
    assert 0.2 < arm / height < 0.6, (what, "arm / height", arm / height)
    # Cartoon characters (Mixamo's Ortiz) have shoulders half as wide as they are tall.
    assert 0.08 < shoulders.mean() / height < 0.6, (what, "shoulders / height")
