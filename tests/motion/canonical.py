"""Checks every human clip's canonical skeleton must pass, whatever format it came from: what a
person looking at the stick figure would check. The same checks judge every human file of
the dev folders (wild-bvh, fbx-gltf, wild-more) and the synthetic rigs."""

from __future__ import annotations

import numpy as np

from app.motion.body import Body
from app.motion.skeleton_map import CANONICAL_INDEX

LIMBS = (("hip", "knee"), ("knee", "ankle"), ("shoulder", "elbow"), ("elbow", "wrist"))


def _joint(body: Body, name: str) -> np.ndarray:
    return body.positions[:, CANONICAL_INDEX[name]]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("fa,fa->f", a, b)


def lateral_axis(body: Body) -> np.ndarray:
    """``(F, 3)`` right-to-left across the legs: the hips, or where the legs part when both
    hip joints sit at the pelvis."""
    for part in ("hip", "knee", "ankle"):
        lateral = _joint(body, f"l_{part}") - _joint(body, f"r_{part}")
        if np.median(np.linalg.norm(lateral, axis=1)) > 1e-4 * body.height:
            return lateral
    raise AssertionError("the left and right legs coincide")


def check_canonical_body(
    body: Body,
    what: str,
    *,
    upright: bool | None = None,
    stretch: dict[tuple[str, str, str], np.ndarray] | None = None,
) -> None:
    """Upright, constant limb lengths, left on the left, human proportions; an AssertionError
    naming the first check that fails.

    ``upright``: ``True`` when the clip stands all along (head over pelvis over ankles in 90 %
    of frames), ``False`` when it need not (a pose sitting, lying, flying), ``None`` when it is
    on its feet most of the time (medians).

    Limb lengths are constant where the file keeps them so: a few frames of a file whose
    position channels change a bone's length (a 3ds Max Biped export does in 2 of 120
    frames) are the data, not the mapping; a wrong joint changes the length in most frames.
    ``stretch``: (side, upper, lower) -> ``(F,)`` the limb's length as the file's own bones
    give it along the mapped joints' chain (a Kinect solver's bones stretch every frame); the
    limb's length then follows that, not a constant.
    """
    up, height = body.world_up, body.height
    head, pelvis = _joint(body, "head") @ up, _joint(body, "pelvis") @ up
    ankles = np.maximum(_joint(body, "l_ankle") @ up, _joint(body, "r_ankle") @ up)
    if upright is not False:  # mostly on its feet, whatever it does for a while
        assert np.median(head - pelvis) > 0.15 * height, (what, "head not above the pelvis")
        assert np.median(head - ankles) > 0.3 * height, (what, "not upright")
    if upright:  # standing all along
        standing = (head > pelvis) & (pelvis > ankles)
        assert standing.mean() >= 0.9, (what, "upright in too few frames", standing.mean())
    for side in ("l", "r"):
        for a, b in LIMBS:
            length = np.linalg.norm(
                _joint(body, f"{side}_{a}") - _joint(body, f"{side}_{b}"), axis=-1
            )
            middle = float(np.median(length))
            assert middle > 0.05 * height, (what, side, a, b, "limb too short")
            own = None if stretch is None else stretch.get((side, a, b))
            if own is not None:  # the file's own stretch: the mapped limb follows it
                length = length / (own / float(np.median(own)))
            off = np.abs(length - middle) / middle
            assert np.median(off) <= 1e-3 and np.mean(off < 0.01) >= 0.95, (
                what, side, a, b, "length varies", float(off.max()),
            )  # fmt: skip
    # Sides. Shoulders lie on the hips' side...
    lateral = lateral_axis(body)
    shoulders = _joint(body, "l_shoulder") - _joint(body, "r_shoulder")
    assert (_dot(lateral, shoulders) > 0).mean() >= 0.9, (what, "shoulders across the hips")
    # ...and the feet turn forward from the shins and bent knees
    # point forward. Only frames that show it are judged: a foot along the shin, an End Site
    # pointing anywhere (derived toes), straight knees, or knees bent sideways (a figure
    # drawn flat in one plane) say nothing about front and back.
    # The pelvis's own forward (lateral x its up, turning with it): a cartwheel turns the body
    # upside down and a deep bow the trunk level, and knees still bend forward.
    forward = body.pelvis_frames[:, :, 2]
    across = lateral / np.linalg.norm(lateral, axis=1, keepdims=True)
    for s in ("l", "r"):
        if body.mapping is not None and body.mapping.how[f"{s}_toe"].startswith("derived"):
            continue
        foot = _joint(body, f"{s}_toe") - _joint(body, f"{s}_ankle")
        shin = _joint(body, f"{s}_ankle") - _joint(body, f"{s}_knee")
        turn = _dot(np.cross(shin, foot), across) / (
            np.linalg.norm(foot, axis=1) * np.linalg.norm(shin, axis=1) + 1e-12
        )
        judged = np.abs(turn) > 0.3
        if judged.mean() >= 0.5:
            assert (turn[judged] < 0).mean() >= 0.8, (what, f"the {s} foot points backwards")
    for s in ("l", "r"):
        hip, knee, ankle = (_joint(body, f"{s}_{j}") for j in ("hip", "knee", "ankle"))
        thigh, shin = knee - hip, ankle - knee
        cos = _dot(thigh, shin) / (np.linalg.norm(thigh, axis=1) * np.linalg.norm(shin, axis=1))
        out = knee - 0.5 * (hip + ankle)
        ahead = _dot(out, forward) / np.linalg.norm(forward, axis=1)
        bent = (cos < np.cos(np.radians(20.0))) & (
            np.abs(ahead) > 0.5 * np.linalg.norm(out, axis=1)
        )
        if bent.sum() >= 3:
            assert (ahead[bent] > 0).mean() >= 0.75, (what, f"the {s} knee bends backwards")
    # Proportions against body height (hip-knee-ankle plus pelvis-to-head). Cartoon and
    # stylised characters stretch them: Mixamo's Ortiz has shoulders half as wide as he is
    # tall, three.js's Michelle legs 0.71 of that height.
    leg = np.mean(
        [
            np.linalg.norm(_joint(body, f"{s}_hip") - _joint(body, f"{s}_knee"), axis=-1)
            + np.linalg.norm(_joint(body, f"{s}_knee") - _joint(body, f"{s}_ankle"), axis=-1)
            for s in ("l", "r")
        ]
    )
    arm = np.mean(
        [
            np.linalg.norm(_joint(body, f"{s}_shoulder") - _joint(body, f"{s}_elbow"), axis=-1)
            + np.linalg.norm(_joint(body, f"{s}_elbow") - _joint(body, f"{s}_wrist"), axis=-1)
            for s in ("l", "r")
        ]
    )
    width = np.linalg.norm(shoulders, axis=-1).mean()
    assert 0.3 < leg / height < 0.75, (what, "leg / height", leg / height)
    assert 0.2 < arm / height < 0.6, (what, "arm / height", arm / height)
    assert 0.08 < width / height < 0.6, (what, "shoulders / height", width / height)
