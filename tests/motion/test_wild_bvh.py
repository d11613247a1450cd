"""Every file of ../shared/data/wild-bvh, with its README's table as the test's table: people
are accepted and their canonical skeleton passes what a person would check looking at it;
the listed files are refused with a message naming the problem."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from app.errors import ParseError
from app.motion.formats import read_bvh
from app.motion.pipeline import analyse
from app.motion.skeleton_map import CANONICAL_INDEX
from tests.conftest import shared_data_dir

WILD = shared_data_dir() / "wild-bvh"
pytestmark = pytest.mark.skipif(
    not (WILD / "README.md").is_file(),
    reason=f"wild-bvh not found at {WILD} (set MOCAP_SHARED_DATA)",
)

# From the README's "What the service should do with each file": refused, and why.
REFUSED = {
    "perception-neuron/pn_pro_template.bvh": "Frames: 0",
    "perception-neuron/pns_template.bvh": "Frames: 0",
    "perception-neuron/pns_thumb_open_template.bvh": "Frames: 0",
    "unity-humanoid/mdm2bvh_sample.bvh": "every OFFSET is 0",
    "parser-breakers/ammarkov_tpose_frames_mismatch.bvh": "says 1352",
    "parser-breakers/ammarkov_daz_bighands_frames_mismatch.bvh": "says 250",
}
# "upright unless the pose itself is not — sitting, lying, flying"
NOT_UPRIGHT_WORDS = ("sit", "lying", "fly")


def _table() -> list[str]:
    """The files the README's table lists (its second column)."""
    if not (WILD / "README.md").is_file():
        return []
    rows = []
    for line in (WILD / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.split("|")]
        if len(cells) > 3 and cells[2].startswith("`") and cells[2].endswith(".bvh`"):
            rows.append(cells[2].strip("`"))
    return rows


FILES = _table()


def test_the_table_lists_every_file():
    on_disk = sorted(str(p.relative_to(WILD)) for p in WILD.rglob("*.bvh"))
    assert sorted(FILES) == on_disk
    assert set(REFUSED) <= set(FILES)


@pytest.mark.parametrize("name", sorted(REFUSED))
def test_refused_with_the_reason(name: str):
    with pytest.raises(ParseError) as refused:  # every ParseError is a 422
        analyse(read_bvh((WILD / name).read_bytes()))
    assert REFUSED[name] in str(refused.value)


def _joint(positions: np.ndarray, name: str) -> np.ndarray:
    return positions[:, CANONICAL_INDEX[name]]


# The world's vertical comes from the clip's mean trunk direction today; this MDM clip leans
# its trunk ~55 degrees all along and the snapped axis is wrong (+y is right: head above
# pelvis above ankles along +y in every frame). Issue #11 takes the vertical from the rest
# pose, which is upright here.
LEANING = {"unity-humanoid/mdm2bvh_results.bvh"}


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(
            n,
            marks=pytest.mark.xfail(
                reason="the generated (MDM) motion has the head below the pelvis or the pelvis "
                "below an ankle in 22 % of its frames",
                strict=True,
            ),
        )
        if n in LEANING
        else n
        for n in sorted(set(FILES) - set(REFUSED))
    ],
)
def test_a_person_is_accepted_and_looks_like_one(name: str):
    analysis = analyse(read_bvh((WILD / name).read_bytes()))
    body = analysis.body
    p, up = body.positions, body.world_up

    def height(joint: str) -> np.ndarray:
        return _joint(p, joint) @ up

    # Upright: head above pelvis above ankles in >= 90 % of frames.
    if not any(word in Path(name).stem for word in NOT_UPRIGHT_WORDS):
        ankles = np.maximum(height("l_ankle"), height("r_ankle"))
        upright = (height("head") > height("pelvis")) & (height("pelvis") > ankles)
        assert upright.mean() >= 0.9, f"upright in {upright.mean():.0%} of frames"

    # Limb bones keep their length (spread < 1 %).
    for a, b in (("shoulder", "elbow"), ("elbow", "wrist"), ("hip", "knee"), ("knee", "ankle")):
        for side in ("l", "r"):
            length = np.linalg.norm(_joint(p, f"{side}_{b}") - _joint(p, f"{side}_{a}"), axis=1)
            assert length.min() > 0, (side, a, b)
            spread = (length.max() - length.min()) / length.mean()
            assert spread < 0.01, f"{side} {a}-{b} length spreads {spread:.1%}"

    # Left and right not swapped: the left shoulder on the left hip's side...
    hips = _joint(p, "l_hip") - _joint(p, "r_hip")
    shoulders = _joint(p, "l_shoulder") - _joint(p, "r_shoulder")
    assert (np.einsum("fa,fa->f", hips, shoulders) > 0).mean() >= 0.9
    # ...the feet point forward: seen from the side, a foot turns from the shin towards the
    # front (shin x foot points to the subject's right), whatever the knee and ankle angles
    # (a runner's rear foot points down and back). Feet lying along the shin, and feet
    # without a toe joint whose End Site points anywhere (Biovision's example ends the leg
    # straight down, la_bvh's End Sites point inwards), say nothing and are not judged...
    forward = np.cross(hips, up)
    lateral = hips / np.linalg.norm(hips, axis=1, keepdims=True)
    for s in ("l", "r"):
        foot = _joint(p, f"{s}_toe") - _joint(p, f"{s}_ankle")
        shin = _joint(p, f"{s}_ankle") - _joint(p, f"{s}_knee")
        turn = np.einsum("fa,fa->f", np.cross(shin, foot), lateral) / (
            np.linalg.norm(foot, axis=1) * np.linalg.norm(shin, axis=1)
        )
        judged = np.abs(turn) > 0.3
        # A foot with no toe joint ends in whatever End Site the converter wrote.
        if judged.mean() >= 0.5 and not body.mapping.how[f"{s}_toe"].startswith("derived"):
            assert (turn[judged] < 0).mean() >= 0.8, f"the {s} foot points backwards"
    # ...and bent knees bend forward.
    for s in ("l", "r"):
        hip, knee, ankle = (_joint(p, f"{s}_{j}") for j in ("hip", "knee", "ankle"))
        thigh, shin = knee - hip, ankle - knee
        cos = np.einsum("fa,fa->f", thigh, shin) / (
            np.linalg.norm(thigh, axis=1) * np.linalg.norm(shin, axis=1)
        )
        bent = cos < np.cos(np.radians(20.0))
        if bent.sum() >= 3:
            ahead = np.einsum("fa,fa->f", knee - 0.5 * (hip + ankle), forward)[bent]
            assert (ahead > 0).mean() >= 0.8, f"{s} knee bends backwards"

    # Plausible proportions (cartoon rigs included): legs and arms against body height.
    leg = np.mean(
        [
            np.linalg.norm(_joint(p, f"{s}_knee") - _joint(p, f"{s}_hip"), axis=1)
            + np.linalg.norm(_joint(p, f"{s}_ankle") - _joint(p, f"{s}_knee"), axis=1)
            for s in ("l", "r")
        ]
    )
    arm = np.mean(
        [
            np.linalg.norm(_joint(p, f"{s}_elbow") - _joint(p, f"{s}_shoulder"), axis=1)
            + np.linalg.norm(_joint(p, f"{s}_wrist") - _joint(p, f"{s}_elbow"), axis=1)
            for s in ("l", "r")
        ]
    )
    assert 0.3 < leg / body.height < 0.7, leg / body.height
    assert 0.2 < arm / body.height < 0.6, arm / body.height
