"""A .gltf with the files it refers to packed into one GLB (app/motion/formats/gltf_pack.py):
what the glTF reader then reads is what the separate files hold."""

from __future__ import annotations

import json
import struct
from typing import Any

import numpy as np
import pytest

from app.errors import ParseError
from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.formats.gltf_data import load_document
from app.motion.formats.gltf_pack import PLACEHOLDER_PNG, pack_gltf, refers_to_files
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import build_glb

VRMA = (FIXTURES_DIR / "three_vrm_test.vrma").read_bytes()


def separate(glb: bytes, bin_name: str = "scene.bin") -> tuple[dict[str, Any], bytes]:
    """A GLB as a writer of separate files lays it out: the JSON document, its buffer
    named by ``bin_name``, and the buffer's bytes."""
    (json_length,) = struct.unpack_from("<I", glb, 12)
    document = json.loads(glb[20 : 20 + json_length])
    start = 20 + json_length
    (bin_length,) = struct.unpack_from("<I", glb, start)
    binary = glb[start + 8 : start + 8 + bin_length]
    document["buffers"][0]["uri"] = bin_name
    return document, binary


def text(document: dict[str, Any]) -> bytes:
    return json.dumps(document, indent=2).encode()


def same_motion(a: bytes, b: bytes) -> None:
    first, second = read_gltf(a)[0], read_gltf(b)[0]
    assert first.skeleton.names == second.skeleton.names
    np.testing.assert_array_equal(first.local_rotations, second.local_rotations)
    np.testing.assert_array_equal(first.root_translation, second.root_translation)
    assert first.frame_time == second.frame_time


def test_a_real_file_laid_out_as_gltf_and_bin_reads_as_the_glb_did() -> None:
    document, binary = separate(VRMA, "anim/test.bin")
    data = text(document)
    assert refers_to_files(data) and not refers_to_files(VRMA)
    with pytest.raises(ParseError, match="external file"):  # the reader alone reads no file
        read_gltf(data)
    packed = pack_gltf(data, {"anim/test.bin": binary})
    same_motion(packed, VRMA)
    # A bare file name finds the file too (an upload's parts carry no folders).
    same_motion(pack_gltf(data, {"test.bin": binary}), VRMA)


def test_several_buffers_become_one_and_every_view_points_into_it() -> None:
    motion = read_bvh((FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())
    glb = build_glb(motion)
    document, binary = separate(glb)
    # The same bytes split in two buffers at a view's edge, the second a data URI.
    views = document["bufferViews"]
    cut = views[len(views) // 2]["byteOffset"]
    import base64

    second = "data:application/octet-stream;base64," + base64.b64encode(binary[cut:]).decode()
    document["buffers"] = [
        {"uri": "a.bin", "byteLength": cut},
        {"uri": second, "byteLength": len(binary) - cut},
    ]
    for view in views[len(views) // 2 :]:
        view["buffer"], view["byteOffset"] = 1, view.get("byteOffset", 0) - cut
    packed = pack_gltf(text(document), {"a.bin": binary[:cut] + b"extra bytes are left out"})
    packed_document, _, _ = load_document(packed)
    assert [b.byteLength for b in packed_document.buffers] == [len(binary) + (-cut % 8)]
    same_motion(packed, glb)


def test_images_sent_are_embedded_and_images_not_sent_become_a_placeholder() -> None:
    document, binary = separate(VRMA)
    document["images"] = [{"uri": "textures/skin%20tone.png"}, {"uri": "eyes.jpg"}]
    document["textures"] = [{"source": 0}, {"source": 1}]
    jpeg = b"\xff\xd8\xff\xe0 not really a jpeg"
    packed = pack_gltf(text(document), {"scene.bin": binary, "eyes.jpg": jpeg})
    out, blob, _ = load_document(packed)
    assert blob is not None
    shown = []
    for image in out.images:
        assert getattr(image, "uri", None) is None
        view = out.bufferViews[image.bufferView]
        offset = view.byteOffset or 0
        shown.append((image.mimeType, blob[offset : offset + view.byteLength]))
    assert shown == [("image/png", PLACEHOLDER_PNG), ("image/jpeg", jpeg)]
    same_motion(packed, VRMA)


@pytest.mark.parametrize(
    ("uri", "message"),
    [
        ("scene.bin", "'scene.bin', which was not sent"),
        ("../scene.bin", "outside the document's folder"),
        ("/etc/passwd", "outside the document's folder"),
        ("file:///etc/passwd", "an address"),
        ("https://example.com/scene.bin", "an address"),
        ("data:application/octet-stream,plain", "only base64 data URIs"),
    ],
)
def test_a_buffer_not_sent_or_out_of_reach_is_refused_naming_it(uri: str, message: str) -> None:
    document, binary = separate(VRMA)
    document["buffers"][0]["uri"] = uri
    with pytest.raises(ParseError, match=message) as caught:
        pack_gltf(text(document), {"other.bin": binary}, what="field 'file': 'test.gltf'")
    assert "buffer 0" in str(caught.value) and "test.gltf" in str(caught.value)


def test_a_file_shorter_than_its_buffer_is_refused() -> None:
    document, binary = separate(VRMA)
    with pytest.raises(ParseError, match=f"fewer than its byteLength {len(binary)}"):
        pack_gltf(text(document), {"scene.bin": binary[:-1]})


@pytest.mark.parametrize("data", [b"[1, 2]", b"{not json", b'{"buffers": 3}'])
def test_what_is_no_gltf_document_is_refused_or_left_to_the_reader(data: bytes) -> None:
    assert not refers_to_files(data)
    if data.startswith(b"{n") or data.startswith(b"["):
        with pytest.raises(ParseError, match="not a JSON glTF document"):
            pack_gltf(data, {})
