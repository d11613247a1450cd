"""The held-out judge (``bench/held_out.py``) on small real fixtures: a person is as expected
as a human, not as a nonhuman; a rig is as expected refused; the names' sides."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.formats.bvh_writer import write_bvh
from bench.held_out import judge, manifest, named_side
from tests.motion.test_gltf_pack import separate

FIXTURES = Path(__file__).parents[1] / "fixtures"
CMU = FIXTURES / "cmu_mb_02_01_first41.bvh"
VRMA = FIXTURES / "three_vrm_test.vrma"


@pytest.mark.parametrize(
    ("name", "side"),
    [
        ("LeftUpLeg", "l"),
        ("mixamorig:RightArm", "r"),
        ("lShldr", "l"),
        ("Bip01 R Thigh", "r"),
        ("UpperLeg.L", "l"),
        ("HandRight", "r"),
        ("left_knee", "l"),
        ("Hips", None),
        ("Spine1", None),
    ],
)
def test_the_names_say_a_side(name: str, side: str | None) -> None:
    assert named_side(name) == side


def test_a_person_is_as_expected_only_as_a_human() -> None:
    assert judge(CMU, "human")["ok"] is True
    assert judge(CMU, "nonhuman")["ok"] is False


def test_a_rig_is_as_expected_refused(tmp_path: Path) -> None:
    text = CMU.read_text()
    rig = tmp_path / "rig.bvh"
    rig.write_text(text.split("MOTION")[0] + "MOTION\nFrames: 0\nFrame Time: 0.008333\n")
    refused = judge(rig, "rig-only")
    assert refused["outcome"] == "refused" and refused["ok"] is True
    (tmp_path / "manifest.tsv").write_text("# header\nrig.bvh\to/r\trig.bvh\tabc\trig-only\tnote\n")
    assert manifest(tmp_path) == {"rig.bvh": "rig-only"}


def test_a_gltf_is_judged_with_the_files_it_names(tmp_path: Path) -> None:
    """Blender's "glTF Separate" and sample folders keep the buffers beside the document; the
    judge reads them from the folder as ``mocap-index import`` does (it refused every such
    file before: "refers to an external file")."""
    document, binary = separate(VRMA.read_bytes(), "anim.bin")
    (tmp_path / "anim.bin").write_bytes(binary)
    (tmp_path / "anim.gltf").write_text(json.dumps(document))
    whole = judge(VRMA, "human")
    separated = judge(tmp_path / "anim.gltf", "human")
    assert separated["outcome"] == whole["outcome"] == "accepted", separated
    assert separated["family"] == whole["family"]


def test_an_asf_without_its_amc_is_refused_as_the_upload_route_does(tmp_path: Path) -> None:
    """A skeleton file alone (round 12 held a test .asf whose repository has no .amc): the
    judge crashed on it; the upload route answers 422, so the judge reads it as refused."""
    lone = tmp_path / "alone.asf"
    lone.write_bytes((FIXTURES / "cmu_02.asf").read_bytes())
    refused = judge(lone, "rig-only")
    assert refused["outcome"] == "refused" and refused["ok"] is True
    assert "must come with an .amc" in refused["why"]


def test_limbs_that_stretch_as_the_files_own_bones_do_are_not_a_wrong_joint(
    tmp_path: Path,
) -> None:
    """A solver that writes every joint's translation each frame (round 12's Kinect files)
    stretches its bones by a few per cent; the mapped limbs follow the file's own bones, so
    the judge does not call their varying length a wrong joint."""
    motion = read_bvh(CMU.read_bytes())
    frames, names = motion.frame_count, motion.skeleton.names
    moving = np.broadcast_to(motion.skeleton.offsets, (frames, len(names), 3)).copy()
    for name in ("LeftLeg", "LeftFoot", "RightLeg", "RightFoot"):
        stretch = 1.0 + 0.03 * np.sin(np.linspace(0.0, 6.0, frames))
        moving[:, names.index(name)] *= stretch[:, None]
    stretched = tmp_path / "stretched.bvh"
    stretched.write_text(write_bvh(dataclasses.replace(motion, local_translations=moving)))
    assert read_bvh(stretched.read_bytes()).local_translations is not None
    row = judge(stretched, "human")
    assert row["ok"] is True, row
