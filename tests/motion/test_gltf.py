"""The glTF / GLB / VRMA reader (app/motion/formats/gltf.py), on files built from the BVH
fixtures (a known motion) and on the real VRM animation fixture."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.errors import LimitExceeded, NoAnimation, ParseError
from app.motion.body import build_body
from app.motion.formats import read_bvh
from app.motion.formats.gltf import list_gltf_animations, read_gltf
from app.motion.kinematics import forward_kinematics
from app.motion.model import ParseLimits
from app.motion.skeleton_map import rest_pose
from tests.conftest import FIXTURES_DIR
from tests.motion.canonical import check_canonical_body
from tests.motion.gltf_builder import (
    build_glb,
    gltf_parts,
    pack_glb,
    with_empty_take,
    with_prop_take,
)

BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"
VRMA = FIXTURES_DIR / "three_vrm_test.vrma"


@pytest.fixture(scope="module")
def bvh_motion():
    return read_bvh(BVH.read_bytes())


def _positions_by_name(motion):
    _, positions = forward_kinematics(motion)
    return {name: positions[:, j] for j, name in enumerate(motion.skeleton.names)}


def test_a_skinned_glb_gives_back_the_motion_it_holds(bvh_motion):
    motion, animations, chosen = read_gltf(build_glb(bvh_motion, name="walk"))
    assert chosen == "walk" and [a.name for a in animations] == ["walk"]
    assert motion.source_format == "gltf" and motion.frame_count == bvh_motion.frame_count
    assert motion.frame_time == pytest.approx(bvh_motion.frame_time, rel=1e-5)
    want, got = _positions_by_name(bvh_motion), _positions_by_name(motion)
    size = np.ptp(np.concatenate(list(want.values())), axis=0).max()
    for name, positions in want.items():
        np.testing.assert_allclose(got[name], positions, atol=1e-5 * size, err_msg=name)


def test_embedded_data_uri_gltf_reads_like_the_glb(bvh_motion):
    document, binary = gltf_parts(bvh_motion)
    document["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    )
    from_json = read_gltf(json.dumps(document).encode())[0]
    from_glb = read_gltf(pack_glb(*gltf_parts(bvh_motion)))[0]
    np.testing.assert_array_equal(from_json.local_rotations, from_glb.local_rotations)


@pytest.mark.parametrize(
    "uri", ["walk.bin", "../secret.bin", "/etc/passwd", "http://example.com/a.bin", "file:///x"]
)
def test_a_uri_that_is_not_embedded_is_refused_without_touching_it(bvh_motion, uri):
    document, _ = gltf_parts(bvh_motion)
    document["buffers"][0]["uri"] = uri
    with pytest.raises(ParseError, match=r"external file.*or a \.glb"):
        read_gltf(json.dumps(document).encode())


def _split_by_node(document: dict) -> dict:
    """``document`` with its one animation written as one unnamed animation per node (how
    COLLADA2GLTF writes a take), each with its own samplers."""
    (whole,) = document["animations"]
    parts: dict[int, dict] = {}
    for channel in whole["channels"]:
        part = parts.setdefault(channel["target"]["node"], {"channels": [], "samplers": []})
        part["samplers"].append(whole["samplers"][channel["sampler"]])
        part["channels"].append({**channel, "sampler": len(part["samplers"]) - 1})
    return {**document, "animations": list(parts.values())}


def test_a_take_written_as_one_animation_per_node_is_read_whole(bvh_motion):
    """A converter that writes each node's channels as an animation of its own (Khronos's
    COLLADA2GLTF sample figures) holds one take: read alone, the first animation was a
    still pose of a body that moves. The parts read together give the whole take, exactly."""
    document, binary = gltf_parts(bvh_motion, name="walk")
    split = _split_by_node(document)
    assert len(split["animations"]) > 2
    data = pack_glb(split, binary)
    (animation,) = list_gltf_animations(data)
    assert animation.name.endswith(f"(one take over {len(split['animations'])} animations)")
    whole, split_read = read_gltf(pack_glb(document, binary))[0], read_gltf(data)[0]
    np.testing.assert_array_equal(split_read.local_rotations, whole.local_rotations)
    np.testing.assert_array_equal(split_read.root_translation, whole.root_translation)
    # Two of the parts moving one node are takes of their own: not joined.
    split["animations"].append(json.loads(json.dumps(split["animations"][0])))
    assert len(list_gltf_animations(pack_glb(split, binary))) == len(split["animations"])


def test_rigid_parts_keyed_one_by_one_are_refused_as_no_body(bvh_motion):
    """A modelling tool's animated model (Blockbench: groups, each holding meshes, turned on
    their own under one root, no skin) has no skeleton; it was refused "every joint of the
    pose is at one point", which is not what is wrong with it. A skeleton without a skin
    (joints hanging from joints) still reads."""
    document, binary = gltf_parts(bvh_motion)
    parts = ["wheel", "eye", "mouth", "body"]
    nodes = [{"name": "root", "children": list(range(1, 1 + len(parts)))}]
    nodes += [{"name": p, "children": [1 + len(parts) + i]} for i, p in enumerate(parts)]
    nodes += [{"name": f"{p} cube", "mesh": 0} for p in parts]
    channels = document["animations"][0]["channels"][: len(parts)]
    for i, channel in enumerate(channels):
        channel["target"]["node"] = 1 + i
    document.update(nodes=nodes, scenes=[{"nodes": [0]}], meshes=[{"primitives": []}])
    document["animations"][0]["channels"] = channels
    del document["skins"]
    with pytest.raises(
        ParseError, match=r"moves 4 parts \(wheel, eye, mouth, body\) each on.* no knees or"
    ):
        read_gltf(pack_glb(document, binary))
    skinless, binary = gltf_parts(bvh_motion)
    del skinless["skins"]
    assert read_gltf(pack_glb(skinless, binary))[0].skeleton.joint_count > 20


def test_several_animations_are_listed_and_one_is_read_by_name(bvh_motion):
    document, binary = gltf_parts(bvh_motion, name="long")
    short = json.loads(json.dumps(document["animations"][0]))
    short["name"] = "short"
    document["animations"].append(short)
    data = pack_glb(document, binary)
    assert [a.name for a in list_gltf_animations(data)] == ["long", "short"]
    assert read_gltf(data, animation="short")[2] == "short"
    with pytest.raises(ParseError, match="'long', 'short'"):
        read_gltf(data, animation="nope")


def test_non_finite_numbers_no_skeleton_and_no_animation_are_told_apart(bvh_motion):
    document, binary = gltf_parts(bvh_motion)
    values = np.frombuffer(binary, dtype=np.float32).copy()
    values[len(values) // 2] = np.nan
    with pytest.raises(ParseError, match="non-finite"):
        read_gltf(pack_glb(document, values.tobytes()))
    nothing = dict(document, skins=[], animations=[])
    with pytest.raises(ParseError, match="no skeleton"):
        read_gltf(pack_glb(nothing, binary))
    still = dict(document, animations=[])
    with pytest.raises(NoAnimation, match="rig with no animation"):
        read_gltf(pack_glb(still, binary))


def test_a_pose_written_as_a_take_is_a_one_frame_still(bvh_motion):
    """A zero-length animation (a bind pose written as a take) is the file's motion: one
    frame, said in the warnings (a file with no animation at all is a rig, above). A take of
    some length that moves no joint (morph weights only) is a pose held for that long: a
    still clip, as a BVH of repeated frames."""
    one_instant = build_glb(bvh_motion.slice_frames(0, 1), name="bind pose")
    pose = read_gltf(one_instant)[0]
    assert pose.frame_count == 1
    assert any("'bind pose' is a single instant" in w for w in pose.notes["warnings"])
    document, binary = gltf_parts(bvh_motion, name="faces")
    for channel in document["animations"][0]["channels"]:
        channel["target"]["path"] = "weights"
    still = read_gltf(pack_glb(document, binary))[0]
    assert still.frame_count == bvh_motion.frame_count
    assert np.ptp(still.local_rotations, axis=0).max() == 0


def test_an_animation_without_its_mesh_or_skin_is_the_nodes_it_moves(bvh_motion):
    # Blender and FBX2glTF export a clip alone: nodes and channels, no skin.
    document, binary = gltf_parts(bvh_motion)
    skinned = read_gltf(pack_glb(document, binary))[0]
    alone = read_gltf(pack_glb(dict(document, skins=[]), binary))[0]
    assert alone.skeleton.names == skinned.skeleton.names
    np.testing.assert_allclose(alone.local_rotations, skinned.local_rotations)


@pytest.mark.parametrize(
    "data",
    [b"glTF\x02\x00\x00\x00\xff\xff\xff\x7f", b"glTF" + bytes(30), b"{", b"\xff\xfe{}", b"[]"],
)
def test_garbage_is_a_parse_error(data):
    with pytest.raises(ParseError):
        read_gltf(data)


def test_frame_limits_are_kept(bvh_motion):
    with pytest.raises(LimitExceeded):
        read_gltf(build_glb(bvh_motion), limits=ParseLimits(max_frames=10))
    with pytest.raises(LimitExceeded):
        read_gltf(build_glb(bvh_motion), limits=ParseLimits(max_joints=5))


def test_vrm_animation_reads_its_humanoid_bones_as_an_upright_person():
    motion, animations, _ = read_gltf(VRMA.read_bytes())
    assert len(animations) == 1
    assert {"hips", "leftUpperArm", "rightFoot"} <= set(motion.skeleton.names)
    check_canonical_body(build_body(motion), VRMA.name)


def test_step_and_cubic_samplers():
    from app.motion.formats.gltf import _sample_channel

    keys = np.array([0.0, 1.0])
    values = np.array([[0.0], [2.0]])
    times = np.array([0.0, 0.5, 1.0])
    np.testing.assert_allclose(
        _sample_channel(keys, values, times, "STEP", 1, "x")[:, 0], [0, 0, 2]
    )
    np.testing.assert_allclose(
        _sample_channel(keys, values, times, "LINEAR", 1, "x")[:, 0], [0, 1, 2]
    )
    # Hermite with zero tangents: smoothstep, 1.0 at the middle.
    cubic = np.array([[0.0], [0.0], [0.0], [0.0], [2.0], [0.0]])
    np.testing.assert_allclose(
        _sample_channel(keys, cubic, times, "CUBICSPLINE", 1, "x")[:, 0], [0, 1, 2]
    )


def test_offsets_summed_are_the_rest_pose_the_file_shows(bvh_motion):
    # Bones with their own orientations in the rest pose (joint orient, as most FBX and glTF
    # rigs have): the motion's offsets are in BVH's convention, frames the world's at rest.
    document, binary = gltf_parts(bvh_motion)
    turn = Rotation.from_euler("xyz", [30, -50, 70], degrees=True)
    for node in document["nodes"][1::3]:
        node["rotation"] = [float(v) for v in turn.as_quat()]
    rest = np.zeros((len(document["nodes"]), 3))
    world = [Rotation.identity()] * len(document["nodes"])
    for parent, node in enumerate(document["nodes"]):  # parents come before their children
        for child in node.get("children", []):
            rest[child] = rest[parent] + world[parent].apply(
                document["nodes"][child]["translation"]
            )
            world[child] = world[parent] * Rotation.from_quat(
                document["nodes"][child].get("rotation", [0, 0, 0, 1])
            )
    motion, _, _ = read_gltf(pack_glb(document, binary))
    shown = {name: rest[i] for i, name in enumerate(bvh_motion.skeleton.names)}
    summed = rest_pose(motion.skeleton)
    for j, name in enumerate(motion.skeleton.names):
        np.testing.assert_allclose(summed[j], shown[name] - rest[0], atol=1e-4, err_msg=name)


def test_an_animation_only_file_without_a_skin_is_read_by_its_animated_nodes(bvh_motion):
    """Clips exported without their character (no skin, no mesh): the nodes the animation
    moves and what hangs from them are the skeleton, and the motion is the skinned file's."""
    document, binary = gltf_parts(bvh_motion, name="walk")
    skinned = read_gltf(pack_glb(document, binary))[0]
    bare = read_gltf(pack_glb(dict(document, skins=[]), binary))[0]
    assert bare.skeleton.names == skinned.skeleton.names
    np.testing.assert_array_equal(bare.local_rotations, skinned.local_rotations)
    np.testing.assert_array_equal(bare.root_translation, skinned.root_translation)


def _as_pointers(document):
    """``document`` with every channel's target written as a KHR_animation_pointer."""
    for channel in document["animations"][0]["channels"]:
        node, path = channel["target"]["node"], channel["target"]["path"]
        channel["target"] = {
            "path": "pointer",
            "extensions": {"KHR_animation_pointer": {"pointer": f"/nodes/{node}/{path}"}},
        }
    document["extensionsUsed"] = ["KHR_animation_pointer"]
    return document


@pytest.mark.parametrize("skins", [True, False], ids=["skinned", "animation-only"])
def test_animation_pointers_to_node_transforms_read_as_plain_channels(bvh_motion, skins):
    """KHR_animation_pointer: a channel names ``/nodes/N/rotation`` by a JSON pointer instead
    of target.node/path; the motion is the plain file's (with or without a skin)."""
    document, binary = gltf_parts(bvh_motion, name="walk")
    if not skins:
        document["skins"] = []
    plain = read_gltf(pack_glb(document, binary))[0]
    pointed = read_gltf(pack_glb(_as_pointers(document), binary))[0]
    assert pointed.skeleton.names == plain.skeleton.names
    np.testing.assert_array_equal(pointed.local_rotations, plain.local_rotations)
    np.testing.assert_array_equal(pointed.root_translation, plain.root_translation)
    assert not pointed.notes.get("warnings")


def test_animation_pointers_to_other_properties_are_left_out_with_a_warning(bvh_motion):
    document, binary = gltf_parts(bvh_motion, name="walk")
    _as_pointers(document)
    animation = document["animations"][0]
    colour = animation["samplers"][0]["output"]  # any VEC4 accessor: a colour's shape
    animation["samplers"].append({"input": 0, "output": colour})
    odd = [
        "/materials/0/pbrMetallicRoughness/baseColorFactor",
        "/nodes/01/rotation",  # not an array index (RFC 6901): not node 1
        "/nodes/1/extensions/KHR_node_visibility/visible",
        "/nodes/1/rotation/0",
        "x" * 5000,
    ]
    for pointer in odd:
        animation["channels"].append(
            {
                "sampler": len(animation["samplers"]) - 1,
                "target": {
                    "path": "pointer",
                    "extensions": {"KHR_animation_pointer": {"pointer": pointer}},
                },
            }
        )
    animation["channels"].append({"sampler": 0, "target": {"path": "pointer"}})
    plain = read_gltf(pack_glb(*gltf_parts(bvh_motion, name="walk")))[0]
    motion = read_gltf(pack_glb(document, binary))[0]
    np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)
    (warning,) = motion.notes["warnings"]
    assert "6 animation channel(s) of KHR_animation_pointer" in warning
    assert "/materials/0/pbrMetallicRoughness/baseColorFactor" in warning and len(warning) < 300


def test_textures_beside_a_gltf_are_never_read_nor_a_reason_to_refuse_it(bvh_motion):
    """Only buffers hold skeleton and motion: a .gltf with embedded buffers whose images
    (textures) lie beside it, or anywhere, is read; nothing of theirs is opened."""
    document, binary = gltf_parts(bvh_motion)
    document["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + base64.b64encode(binary).decode()
    )
    document["images"] = [{"uri": "skin.png"}, {"uri": "../../etc/passwd"}, {"uri": "http://x/y"}]
    document["extensionsRequired"] = ["KHR_texture_transform", "KHR_texture_basisu"]
    motion = read_gltf(json.dumps(document).encode())[0]
    assert motion.frame_count == bvh_motion.frame_count


def test_a_morph_weights_animation_without_a_skeleton_says_so(bvh_motion):
    """A creature or a face that deforms by blend shapes (three.js's horse, flamingo):
    no skeleton, and the refusal says its animation changes only morph-target weights."""
    document, binary = gltf_parts(bvh_motion)
    for channel in document["animations"][0]["channels"]:
        channel["target"]["path"] = "weights"
    with pytest.raises(ParseError, match=r"no skeleton .*morph-target weights"):
        read_gltf(pack_glb(dict(document, skins=[]), binary))


def test_the_default_animation_is_the_longest_that_moves_a_node(bvh_motion):
    """An empty take longer than the real one (the FBX SDK's "Take 001" beside Mixamo's
    take) is not read by default: the clip would be a held bind pose, the motion lost."""
    data = with_empty_take(bvh_motion)
    animations = list_gltf_animations(data)
    assert [(a.name, a.moves) for a in animations] == [("Take 001", False), ("walk", True)]
    assert animations[0].frame_count > animations[1].frame_count
    motion, _, chosen = read_gltf(data)
    assert chosen == "walk" and motion.frame_count == bvh_motion.frame_count
    (warning,) = motion.notes["warnings"]
    assert "'walk', the longest that moves a node, is read" in warning
    assert "moving nothing: 'Take 001'" in warning
    still, _, _ = read_gltf(data, animation="Take 001")  # named: read as what it is
    assert np.ptp(still.local_rotations, axis=0).max() == 0


def test_an_animation_of_a_node_outside_the_skeleton_is_not_read_by_default(bvh_motion):
    """Blender writes an animation per animated object: a prop's, longer than the body's,
    moves no node of the skeleton, so the clip would be a held pose; the body's is read."""
    data = with_prop_take(bvh_motion)
    motion, animations, chosen = read_gltf(data)
    assert [(a.name, a.moves) for a in animations] == [("prop", False), ("walk", True)]
    assert chosen == "walk" and motion.frame_count == bvh_motion.frame_count
    assert "moving nothing: 'prop'" in motion.notes["warnings"][0]


def test_an_animation_without_keyframes_on_a_skinless_file_is_named_in_the_refusal(bvh_motion):
    """three.js's GLTFExporter drops the tracks it cannot bind (names with a ':') and writes
    the animation empty: the file's bones are plain nodes that nothing moves. Refused as a
    static model, naming the animation that holds nothing rather than saying there is none."""
    document, binary = gltf_parts(bvh_motion)
    empty = {"name": "animation", "channels": [], "samplers": []}
    with pytest.raises(ParseError, match=r"no animation \(its animations 'animation' hold no"):
        read_gltf(pack_glb(dict(document, skins=[], animations=[empty]), binary))
    with pytest.raises(ParseError, match=r"and no animation: a static model"):
        read_gltf(pack_glb(dict(document, skins=[], animations=[]), binary))


def test_a_rig_without_animation_is_read_as_its_rest_pose_when_asked(bvh_motion):
    """``still``: a GLB character with no animation is one frame of its rest pose (a rig
    for retargeting), with nothing to mark as moving or not."""
    document, binary = gltf_parts(bvh_motion)
    motion, animations, _ = read_gltf(pack_glb(dict(document, animations=[]), binary), still=True)
    assert motion.frame_count == 1 and [a.frame_count for a in animations] == [1]


@pytest.mark.parametrize(
    "target", [{"node": 999, "path": "rotation"}, {"node": "0", "path": "scale"}]
)
def test_a_channel_aimed_at_a_node_that_does_not_exist_is_a_malformed_file(bvh_motion, target):
    """The spec: a channel's target node is one of the file's nodes (the glTF validator's
    unresolved_channel_target); such a file is damaged, not a skeleton missing a part."""
    document, binary = gltf_parts(bvh_motion, name="walk")
    document["animations"][0]["channels"][3]["target"] = target
    with pytest.raises(
        ParseError,
        match=r"'walk': glTF animations\[0\]\.channels\[3\]\.target\.node: expected an index "
        r"of nodes \(0-\d+\), found (999|'0')",
    ):
        read_gltf(pack_glb(document, binary))


def test_a_second_skeleton_beside_the_read_one_is_said(bvh_motion):
    """A second, smaller skin on nodes of its own (a prop's rig, another character): the
    skeleton with the most bones is read as before, and a warning says the other was not."""
    document, binary = gltf_parts(bvh_motion)
    first = len(document["nodes"])
    document["nodes"] += [{"name": "PropRoot", "children": [first + 1]}, {"name": "PropTip"}]
    document["scenes"][0]["nodes"].append(first)
    document["skins"].append({"joints": [first, first + 1]})
    motion = read_gltf(pack_glb(document, binary))[0]
    plain = read_gltf(pack_glb(*gltf_parts(bvh_motion)))[0]
    assert motion.skeleton.names == plain.skeleton.names
    np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)
    assert "the file holds 1 other skeleton (2 bones not joined to this one)" in " ".join(
        motion.notes["warnings"]
    )
    assert not any("other skeleton" in w for w in plain.notes.get("warnings", []))
