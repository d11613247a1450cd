"""The GLB writer against the glTF 2.0 specification's rules, and read back."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.formats.gltf_writer import write_glb
from app.motion.kinematics import forward_kinematics
from app.motion.retarget import axis_change
from app.motion.transforms import change_basis
from tests.motion.conftest import BANDAI_FIXTURE, CMU_BVH_FIXTURE, fixture_bytes

COMPONENTS = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}


def chunks(data: bytes) -> tuple[dict, bytes]:
    """The JSON document and binary chunk, checking the container rules on the way."""
    magic, version, length = struct.unpack("<III", data[:12])
    assert magic == 0x46546C67 and version == 2 and length == len(data)
    json_length, json_type = struct.unpack("<II", data[12:20])
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    text = data[20 : 20 + json_length]
    assert text.decode("utf-8") == text.decode("utf-8").rstrip(" ") + " " * (
        len(text) - len(text.decode("utf-8").rstrip(" "))
    )  # padded with spaces only
    offset = 20 + json_length
    bin_length, bin_type = struct.unpack("<II", data[offset : offset + 8])
    assert bin_type == 0x004E4942 and bin_length % 4 == 0
    assert offset + 8 + bin_length == len(data)
    return json.loads(text), data[offset + 8 :]


def accessor(document: dict, blob: bytes, index: int) -> np.ndarray:
    item = document["accessors"][index]
    view = document["bufferViews"][item["bufferView"]]
    assert item["componentType"] == 5126  # float
    start = view["byteOffset"] + item.get("byteOffset", 0)
    assert start % 4 == 0  # aligned to the component size
    width = COMPONENTS[item["type"]]
    assert view["byteLength"] >= item["count"] * width * 4
    values = np.frombuffer(blob, "<f4", item["count"] * width, start)
    return values.reshape(item["count"], width)


@pytest.fixture(scope="module", params=[CMU_BVH_FIXTURE, BANDAI_FIXTURE])
def written(request: pytest.FixtureRequest) -> tuple:
    motion = read_bvh(fixture_bytes(request.param))
    return motion, write_glb(motion, metres_per_unit=0.01)


def test_the_file_follows_the_specs_rules(written: tuple) -> None:
    motion, data = written
    document, blob = chunks(data)
    assert document["asset"]["version"] == "2.0"
    nodes = document["nodes"]
    assert [n["name"] for n in nodes] == list(motion.skeleton.names)
    # A tree: every node but the root is the child of exactly one node; the scene lists
    # the root only.
    children = [c for n in nodes for c in n.get("children", [])]
    assert sorted(children) == list(range(1, len(nodes)))
    assert document["scenes"][0]["nodes"] == [0]
    skin = document["skins"][0]
    assert skin["joints"] == list(range(len(nodes))) and skin["skeleton"] == 0
    matrices = accessor(document, blob, skin["inverseBindMatrices"])
    assert matrices.shape == (len(nodes), 16)
    animation = document["animations"][0]
    for channel in animation["channels"]:
        sampler = animation["samplers"][channel["sampler"]]
        assert sampler["interpolation"] == "LINEAR"
        times_item = document["accessors"][sampler["input"]]
        assert "min" in times_item and "max" in times_item  # required for sampler inputs
        times = accessor(document, blob, sampler["input"])[:, 0]
        assert np.all(np.diff(times) > 0)
        assert times_item["min"] == [float(times.min())] and times_item["max"] == [
            float(times.max())
        ]
        output = accessor(document, blob, sampler["output"])
        assert len(output) == len(times) == motion.frame_count
        assert np.all(np.isfinite(output))
        node = nodes[channel["target"]["node"]]
        assert "matrix" not in node  # animated nodes use TRS
        if channel["target"]["path"] == "rotation":
            np.testing.assert_allclose(np.linalg.norm(output, axis=1), 1.0, atol=5e-7)
            # Consecutive quaternions on one hemisphere: interpolation takes the short way.
            assert np.all(np.sum(output[1:] * output[:-1], axis=1) >= 0)
    paths = {(c["target"]["node"], c["target"]["path"]) for c in animation["channels"]}
    assert (0, "translation") in paths


def test_inverse_bind_matrices_invert_the_rest_pose(written: tuple) -> None:
    motion, data = written
    document, blob = chunks(data)
    ibm = accessor(document, blob, document["skins"][0]["inverseBindMatrices"])
    ibm = ibm.reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
    nodes = document["nodes"]
    world = np.zeros((len(nodes), 4, 4))
    for j, node in enumerate(nodes):
        local = np.eye(4)
        local[:3, 3] = node.get("translation", [0, 0, 0])
        world[j] = local if j == 0 else world[motion.skeleton.parents[j]] @ local
    np.testing.assert_allclose(ibm @ world, np.broadcast_to(np.eye(4), world.shape), atol=1e-5)


def test_read_back_every_joint_is_where_it_was_in_metres(written: tuple) -> None:
    motion, data = written
    back, _, _ = read_gltf(data)
    assert back.frame_count == motion.frame_count
    assert 1 / back.frame_time == pytest.approx(1 / motion.frame_time, rel=1e-4)
    _, before = forward_kinematics(motion)
    _, after = forward_kinematics(back)
    order = [back.skeleton.names.index(n) for n in motion.skeleton.names]
    size = float(np.ptp(before[0], axis=0).max()) * 0.01
    np.testing.assert_allclose(after[:, order], before * 0.01, atol=1e-5 * size)


def test_a_z_up_clip_is_turned_to_y_up() -> None:
    motion = read_bvh(fixture_bytes(CMU_BVH_FIXTURE))
    z_up = change_basis(motion, np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]))
    turn = axis_change(np.array([0.0, 0, 1]), np.array([0.0, 1, 0]))
    back, _, _ = read_gltf(write_glb(z_up, up_rotation=turn))
    _, before = forward_kinematics(motion)
    _, after = forward_kinematics(back)
    order = [back.skeleton.names.index(n) for n in motion.skeleton.names]
    np.testing.assert_allclose(after[:, order], before, atol=1e-4)
