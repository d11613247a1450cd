"""The FBX exporter's animation bake computed in numpy (app/motion/formats/fbx_bake.py).

* Its Euler angles are Blender's: the same rule as ``Quaternion.to_euler('XYZ', compat)``
  (transcribed below literally from Blender's C, frame after frame) on fast, wrapping and
  gimbal-locked rotation sequences.
* A file written with it equals, curve for curve as ufbx reads them, the one Blender's own
  bake writes (Blender in a process of its own: ``fbx_bake_runner.py``), and the numpy
  bake did take the scene over.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.motion.formats.fbx_bake import compatible_eulers
from tests.api.exporting import need_fbx

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"
RUNNER = Path(__file__).with_name("fbx_bake_runner.py")
FLT_EPSILON = float(np.finfo(np.float32).eps)
TURN = 2.0 * math.pi


def _two_eulers(matrix: np.ndarray) -> tuple[list[float], list[float]]:
    """Blender's mat3_normalized_to_eul2 (``mat[col][row]``, hence the transpose)."""
    m = matrix.T
    cy = math.hypot(m[0][0], m[0][1])
    if cy > 16.0 * FLT_EPSILON:
        first = [
            math.atan2(m[1][2], m[2][2]),
            math.atan2(-m[0][2], cy),
            math.atan2(m[0][1], m[0][0]),
        ]
        second = [
            math.atan2(-m[1][2], -m[2][2]),
            math.atan2(-m[0][2], -cy),
            math.atan2(-m[0][1], -m[0][0]),
        ]
        return first, second
    first = [math.atan2(-m[2][1], m[1][1]), math.atan2(-m[0][2], cy), 0.0]
    return first, list(first)


def _compatible_eul(eul: list[float], old: list[float]) -> None:
    """Blender's compatible_eul, in place."""
    deul = [0.0, 0.0, 0.0]
    for i in range(3):
        deul[i] = eul[i] - old[i]
        if deul[i] > math.pi:
            eul[i] -= math.floor(deul[i] / TURN + 0.5) * TURN
            deul[i] = eul[i] - old[i]
        elif deul[i] < -math.pi:
            eul[i] += math.floor(-deul[i] / TURN + 0.5) * TURN
            deul[i] = eul[i] - old[i]
    j, k = 1, 2
    for i in range(3):
        if abs(deul[i]) > math.pi and abs(deul[j]) < math.pi / 2 and abs(deul[k]) < math.pi / 2:
            eul[i] += -TURN if deul[i] > 0 else TURN
        j, k = k, i


def blender_eulers(rotations: np.ndarray) -> np.ndarray:
    """``(F, 3)`` what the exporter's bake writes for ``(F, 3, 3)`` rotations: the first
    frame's ``to_euler('XYZ')`` (the smaller solution), then each frame's
    ``to_euler('XYZ', previous)`` (mat3_normalized_to_compatible_eul)."""
    first, second = _two_eulers(rotations[0])
    previous = first if sum(map(abs, first)) <= sum(map(abs, second)) else second
    out = []
    for matrix in rotations:
        one, two = _two_eulers(matrix)
        _compatible_eul(one, previous)
        _compatible_eul(two, previous)
        d1 = sum(abs(a - b) for a, b in zip(one, previous, strict=True))
        d2 = sum(abs(a - b) for a, b in zip(two, previous, strict=True))
        previous = two if d1 > d2 else one
        out.append(previous)
    return np.array(out)


def rotation_paths(count: int, frames: int, seed: int) -> np.ndarray:
    """``(count, frames, 3, 3)``: smooth turns, fast spins (steps near half a turn), and
    passes through pitch ±90° (exactly, on some frames)."""
    rng = np.random.default_rng(seed)
    paths = []
    for n in range(count):
        speed = rng.uniform(0.02, 2.5, size=3) if n % 2 else rng.uniform(0.001, 0.2, size=3)
        angles = np.cumsum(rng.normal(size=(frames, 3)) * speed, axis=0)
        if n % 3 == 0:
            angles[::7, 1] = np.pi / 2 * np.sign(np.sin(np.arange(0, frames, 7)) + 0.5)
        paths.append(Rotation.from_euler("xyz", angles).as_matrix())
    return np.stack(paths)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_eulers_are_blenders_frame_after_frame(seed: int) -> None:
    rotations = rotation_paths(6, 300, seed)
    expected = np.stack([blender_eulers(path) for path in rotations])
    got = compatible_eulers(rotations, expected[:, 0])
    np.testing.assert_allclose(got, expected, atol=1e-9)
    # The angles are the rotations (Blender's XYZ: X first, Z last), and continuous.
    back = Rotation.from_euler("xyz", got.reshape(-1, 3)).as_matrix().reshape(rotations.shape)
    np.testing.assert_allclose(back, rotations, atol=1e-9)
    assert np.abs(np.diff(got, axis=1)).max() <= np.pi + 1e-9


def test_a_still_pose_and_one_frame() -> None:
    still = np.broadcast_to(Rotation.from_euler("xyz", [0.3, -1.2, 2.9]).as_matrix(), (2, 5, 3, 3))
    start = blender_eulers(still[0])[0]
    got = compatible_eulers(np.ascontiguousarray(still), np.stack([start, start]))
    np.testing.assert_allclose(got, np.broadcast_to(start, got.shape), atol=1e-12)
    one = compatible_eulers(np.ascontiguousarray(still[:, :1]), np.stack([start, start]))
    assert one.shape == (2, 1, 3)


# ufbx's Python binding is C code that has crashed the test process reading these files
# (objects freed under it): it reads them in a process of its own, as the service's own
# readers do, and sends back the node names and every curve's key values.
_READ_CURVES = """
import json, sys
import ufbx
scene = ufbx.load_memory(open(sys.argv[1], "rb").read())
nodes = list(scene.nodes)
curves = list(scene.anim_curves)
keys = [list(curve.keyframes) for curve in curves]
print(json.dumps([sorted(n.name for n in nodes), [[k.value for k in one] for one in keys]]))
"""


def ufbx_curves(path: Path) -> tuple[list[str], list[np.ndarray]]:
    done = subprocess.run(
        [sys.executable, "-c", _READ_CURVES, str(path)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    names, values = json.loads(done.stdout)
    return names, [np.array(one, dtype=np.float64) for one in values]


def write_both(fixture: str, folder: Path, *extra: str) -> list[str | None]:
    """Both files of ``fixture`` in ``folder`` (fbx_bake_runner.py); the bake's refusals."""
    need_fbx()
    done = subprocess.run(
        [sys.executable, str(RUNNER), str(FIXTURES / fixture), str(folder), *extra],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    refusals: list[str | None] = json.loads(done.stdout.strip().splitlines()[-1])
    return refusals


@pytest.mark.parametrize(
    "fixture", ["cmu_mb_02_01_first41.bvh", "bandai_walk_normal_001_first40.bvh"]
)
def test_the_numpy_bake_writes_blenders_file(tmp_path: Path, fixture: str) -> None:
    assert write_both(fixture, tmp_path) == [None]  # baked, not refused
    assert_same_curves(tmp_path)


def test_a_scene_the_bake_refuses_is_written_with_blenders_bake(tmp_path: Path) -> None:
    refusals = write_both("cmu_mb_02_01_first41.bvh", tmp_path, "refuse")
    assert len(refusals) == 1 and "posed otherwise" in str(refusals[0])
    assert_same_curves(tmp_path)  # the animation is there: exported again, Blender's way


def assert_same_curves(tmp_path: Path) -> None:
    names, fast = ufbx_curves(tmp_path / "numpy.fbx")
    blender_names, slow = ufbx_curves(tmp_path / "blender.fbx")
    assert names == blender_names
    assert len(fast) == len(slow) > 0
    for ours, theirs in zip(fast, slow, strict=True):
        assert ours.shape == theirs.shape
        # Blender computes in single precision: agreement to its rounding.
        np.testing.assert_allclose(ours, theirs, atol=1e-4 * max(1.0, np.abs(theirs).max()))
