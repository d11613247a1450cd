"""glTF buffer views compressed with ``EXT_meshopt_compression`` (app/motion/formats/meshopt.py):
decoded as the specification says — checked against a test encoder written from the same
specification (tests/motion/meshopt_encoder.py) on a real BVH fixture's motion, and against
a file gltfpack wrote (../shared)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import ParseError
from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.formats.gltf_data import accessor_values, buffers_of, load_document
from app.motion.formats.meshopt import decode_attributes
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import gltf_parts, pack_glb
from tests.motion.meshopt_encoder import encode_attributes, exponential_filter, quaternion_filter

EXTENSION = "EXT_meshopt_compression"


@pytest.fixture(scope="module")
def motion():
    return read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())


@pytest.mark.parametrize("stride", [4, 8, 12, 64])
@pytest.mark.parametrize("count", [1, 15, 16, 17, 300, 1000])
def test_attribute_streams_read_back(stride: int, count: int) -> None:
    rng = np.random.default_rng(stride * 1000 + count)
    elements = np.cumsum(rng.integers(-3, 4, (count, stride)), axis=0) & 0xFF
    jumps = slice(count // 2, count // 2 + 5)  # whole-byte deltas beside small ones
    elements[jumps] = rng.integers(0, 256, elements[jumps].shape)
    elements = elements.astype(np.uint8)
    stream = encode_attributes(elements)
    np.testing.assert_array_equal(decode_attributes(stream, count, stride, "view"), elements)


def _compressed(motion: Any) -> tuple[dict[str, Any], bytes]:
    """The fixture as gltfpack-like output: every animation view compressed into the GLB's
    buffer, decoding into a fallback buffer without data; rotations as 16-bit quaternions."""
    document, binary = gltf_parts(motion)
    packed, fallback = bytearray(), 0
    channels = {s["output"]: "" for s in document["animations"][0]["samplers"]}
    for sampler in document["animations"][0]["samplers"]:
        channels[sampler["input"]] = "time"
    for channel in document["animations"][0]["channels"]:
        output = document["animations"][0]["samplers"][channel["sampler"]]["output"]
        channels[output] = channel["target"]["path"]
    for index, path in channels.items():
        accessor = document["accessors"][index]
        view = document["bufferViews"][accessor["bufferView"]]
        width = {"time": 1, "rotation": 4, "translation": 3}[path]
        values = np.frombuffer(binary, "<f4", accessor["count"] * width, view["byteOffset"])
        values = values.reshape(-1, width)
        if path == "rotation":
            elements, name = quaternion_filter(values), "QUATERNION"
            accessor.update(componentType=5122, normalized=True)
        elif path == "translation":
            elements, name = exponential_filter(values), "EXPONENTIAL"
        else:
            elements, name = values.view(np.uint8).reshape(len(values), 4), "NONE"
        stream = encode_attributes(np.ascontiguousarray(elements))
        packed += bytes(-len(packed) % 4)
        settings = {"buffer": 0, "byteOffset": len(packed), "byteLength": len(stream)}
        settings.update(byteStride=elements.shape[1], count=len(elements), mode="ATTRIBUTES")
        settings["filter"] = name
        packed += stream
        length = elements.size
        view.update(buffer=1, byteOffset=fallback, byteLength=length)
        view["extensions"] = {EXTENSION: settings}
        fallback += length + (-length % 4)
    document["buffers"] = [
        {"byteLength": len(packed)},
        {"byteLength": fallback, "extensions": {EXTENSION: {"fallback": True}}},
    ]
    document["extensionsUsed"] = document["extensionsRequired"] = [EXTENSION]
    return document, bytes(packed)


def test_a_compressed_animation_reads_as_the_plain_one(motion) -> None:
    plain, _, _ = read_gltf(pack_glb(*gltf_parts(motion)))
    document, packed = _compressed(motion)
    compressed, _, _ = read_gltf(pack_glb(document, packed))
    assert compressed.frame_count == plain.frame_count
    assert compressed.frame_time == pytest.approx(plain.frame_time)
    np.testing.assert_allclose(compressed.root_translation, plain.root_translation, rtol=1e-5)
    turns = Rotation.from_matrix(compressed.local_rotations.reshape(-1, 3, 3)).inv() * (
        Rotation.from_matrix(plain.local_rotations.reshape(-1, 3, 3))
    )
    assert np.degrees(turns.magnitude()).max() < 0.05  # 16-bit components


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda s: s.update(byteLength=s["byteLength"] - 7), "length does not match|truncated"),
        (lambda s: s.update(mode="TRIANGLES"), "mesh indices"),
        (lambda s: s.update(filter="SPIRAL"), "unknown EXT_meshopt_compression filter"),
        (lambda s: s.update(byteOffset=10**9), "runs past the end"),
        (lambda s: s.update(byteStride=6), "stride of 6"),
    ],
)
def test_damaged_compressed_views_are_parse_errors(motion, damage, message) -> None:
    document, packed = _compressed(motion)
    sampler = document["animations"][0]["samplers"][0]
    view = document["accessors"][sampler["output"]]["bufferView"]
    damage(document["bufferViews"][view]["extensions"][EXTENSION])
    with pytest.raises(ParseError, match=message):
        read_gltf(pack_glb(document, packed))


def test_a_stream_of_another_codec_version_is_refused() -> None:
    elements = np.arange(64, dtype=np.uint8).reshape(16, 4)
    stream = bytearray(encode_attributes(elements))
    stream[0] = 0xA1
    with pytest.raises(ParseError, match="header 0xa1"):
        decode_attributes(bytes(stream), 16, 4, "view 3")


def test_gltfpacks_own_output_decodes_to_a_smooth_face_take(shared_data) -> None:
    """A real gltfpack 0.16 file (a face capture: head and eyes turn): keyframe times
    increase evenly, rotations are unit quaternions that change little from key to key."""
    path = shared_data("wild-more", "threejs-examples", "danielrmz18_facecap.glb")
    document, blob, _ = load_document(path.read_bytes())
    buffers = buffers_of(document, blob)
    assert buffers.data[1] == b""  # the fallback buffer holds nothing
    for sampler in document.animations[0].samplers:
        times = accessor_values(document, buffers, sampler.input)[:, 0]
        assert len(times) == 335 and times[-1] == pytest.approx(11.18, abs=0.01)
        np.testing.assert_allclose(np.diff(times), 1 / 30, atol=1e-4)
    for animation in document.animations[1:]:
        for sampler in animation.samplers:
            values = accessor_values(document, buffers, sampler.output)
            if values.shape[1] == 4:
                np.testing.assert_allclose(np.linalg.norm(values, axis=1), 1.0, atol=1e-4)
                steps = np.abs(np.sum(values[1:] * values[:-1], axis=1))
                assert np.degrees(2 * np.arccos(np.minimum(steps, 1.0))).max() < 10


def test_a_count_the_data_cannot_hold_is_refused_before_allocating() -> None:
    stream = encode_attributes(np.zeros((16, 4), dtype=np.uint8))
    with pytest.raises(ParseError, match="10000000000 elements claimed"):
        decode_attributes(stream, 10**10, 4, "view 0")
