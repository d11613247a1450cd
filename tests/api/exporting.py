"""Helpers of the export tests: the fixtures as uploads, Blender as an independent reader,
the skip-or-fail rule for FBX, and the service's own expectation of an export."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.services.export_pool import fbx_unavailable_reason
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import pack_glb, two_animation_glb

BVH = ("walk.bvh", (FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())
BANDAI = ("bandai walk.bvh", (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_bytes())
ASF = ("02.asf", (FIXTURES_DIR / "cmu_02.asf").read_bytes())
AMC = ("02_01.amc", (FIXTURES_DIR / "cmu_02_01_first40.amc").read_bytes())
FBX = ("human_ik.fbx", (FIXTURES_DIR / "ufbx_maya_human_ik_7400_binary.fbx").read_bytes())
GLB = ("walk.glb", two_animation_glb(read_bvh(BVH[1])))
VRMA = ("test.vrma", (FIXTURES_DIR / "three_vrm_test.vrma").read_bytes())

SOURCES = {
    "bvh": {"file": BVH},
    "asf/amc": {"skeleton": ASF, "motion": AMC},
    "fbx": {"file": FBX},
    "glb": {"file": GLB},
    "vrma": {"file": VRMA},
}
READER = Path(__file__).with_name("blender_reader.py")


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def need_fbx() -> None:
    """Skip (fail in CI) when Blender's Python module is not installed here."""
    reason = fbx_unavailable_reason()
    if reason is None:
        return
    if in_ci():
        pytest.fail(f"{reason} (CI: the FBX tests must run)")
    pytest.skip(reason)


def without_animation(glb: bytes) -> bytes:
    """The same GLB with its animations removed: a character (skin) and no motion."""
    length = int.from_bytes(glb[12:16], "little")
    document = json.loads(glb[20 : 20 + length])
    document.pop("animations", None)
    binary = glb[20 + length + 8 :]
    return pack_glb(document, binary)


def frames_zero(bvh: bytes) -> bytes:
    """The BVH's hierarchy with ``Frames: 0`` and no frames: a template without motion."""
    text = bvh.decode()
    head = text[: text.upper().index("MOTION")]
    return (head + "MOTION\nFrames: 0\nFrame Time: 0.0333333\n").encode()


def blender_read(paths: list[Path], frames: list[int]) -> list[dict]:
    """Read files with Blender's importers in a separate process (see blender_reader.py)."""
    request = json.dumps([{"path": str(p), "frames": frames} for p in paths])
    done = subprocess.run(
        [sys.executable, str(READER)],
        input=request,
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    return json.loads(done.stdout)


def five_frames(count: int) -> list[int]:
    return sorted({round(i * (count - 1) / 4) for i in range(5)})


def heads(result: dict, frame: int, names: list[str]) -> np.ndarray:
    """``(J, 3)`` the reader's joint positions of ``names`` at ``frame``."""
    table = result["frames"][str(frame)]
    return np.array([table[n] for n in names])
