"""app/motion/formats/gltf_schema.py: a glTF document's fields of the wrong type are refused
naming the field, or passed over where the file's part is not what is read; never a crash
of the reader (a ``TypeError`` deep in it was a 422 "the reader failed" at best)."""

from __future__ import annotations

import copy
import json
import random
from typing import Any

import numpy as np
import pytest

from app.errors import MocapError, ParseError
from app.motion.formats import read_bvh
from app.motion.formats.gltf import read_gltf
from tests.conftest import FIXTURES_DIR
from tests.motion.gltf_builder import gltf_parts, multi_animation_glb, pack_glb

BVH = FIXTURES_DIR / "cmu_mb_02_01_first41.bvh"


@pytest.fixture(scope="module")
def parts() -> tuple[dict[str, Any], bytes]:
    return gltf_parts(read_bvh(BVH.read_bytes()), name="walk")


def _read(document: dict[str, Any], binary: bytes, **options: Any) -> Any:
    return read_gltf(pack_glb(document, binary), **options)


# Values of the wrong kind for any field: what the fuzzing below puts where the spec asks
# for an index, a number, a string, a list or an object.
ODD = [None, -1, 2**31, 1e308, -0.0, float("nan"), "x", "", [], {}, [0], [0, 0, 0, 0], True]


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    found = [prefix] if prefix else []
    if isinstance(node, dict):
        for key, value in node.items():
            found += _paths(value, (*prefix, key))
    elif isinstance(node, list):
        for i, value in enumerate(node[:4]):
            found += _paths(value, (*prefix, i))
    return found


def test_any_field_of_the_wrong_kind_is_read_or_refused_never_a_crash(parts) -> None:
    """400 seeded documents, each with one to three fields replaced by a value of another
    kind or deleted (the nodes, skin, animation, accessors and buffer views a reader reads):
    each is read, or refused with a MocapError. Before the schema check 47 of them raised
    another exception inside the reader (71 read, 282 refused)."""
    document, binary = parts
    every = [p for p in _paths(document) if p[0] != "asset"]
    outcomes = {"read": 0, "refused": 0}
    for seed in range(400):
        rng = random.Random(seed)
        mutated = copy.deepcopy(document)
        for _ in range(rng.randint(1, 3)):
            path = rng.choice(every)
            parent: Any = mutated
            try:
                for key in path[:-1]:
                    parent = parent[key]
                if rng.random() < 0.15 and isinstance(parent, dict):
                    parent.pop(path[-1], None)
                else:
                    parent[path[-1]] = rng.choice(ODD)
            except (KeyError, IndexError, TypeError):
                continue  # an earlier change removed that place
        try:
            _read(mutated, binary)
            outcomes["read"] += 1
        except MocapError:
            outcomes["refused"] += 1
    assert outcomes["read"] > 50 and outcomes["refused"] > 50, outcomes


@pytest.mark.parametrize(
    "change, named",
    [
        (lambda d: d["accessors"][3].update(count="41"), r"accessors\[3\]\.count"),
        (lambda d: d["bufferViews"][2].update(buffer=7), r"bufferViews\[2\]\.buffer"),
        (lambda d: d["nodes"][1].update(children=4), r"nodes\[1\]\.children"),
        (lambda d: d["nodes"][2].update(rotation=[0, 0, "1", 0]), r"nodes\[2\]\.rotation"),
        (lambda d: d["animations"][0]["samplers"][5].update(output=[5]), r"samplers\[5\]\.output"),
        (lambda d: d["animations"][0].update(samplers=5), r"animations\[0\]\.samplers"),
    ],
)
def test_a_field_of_the_wrong_kind_is_named(parts, change, named) -> None:
    document, binary = copy.deepcopy(parts[0]), parts[1]
    change(document)
    with pytest.raises(ParseError, match=named):
        _read(document, binary)


def test_integers_written_as_whole_floats_and_names_that_are_no_strings_are_read(parts) -> None:
    """A writer's ``30.0`` for an integer is that integer; a name that is no string is no
    name (the node is named as unnamed nodes are)."""
    plain, _, _ = _read(*parts)
    document, binary = copy.deepcopy(parts[0]), parts[1]
    for accessor in document["accessors"]:
        accessor["count"] = float(accessor["count"])
        accessor["bufferView"] = float(accessor["bufferView"])
    document["animations"][0]["samplers"][0]["input"] = 0.0
    document["nodes"][3]["name"] = 17
    motion, _, _ = _read(document, binary)
    np.testing.assert_array_equal(motion.local_rotations, plain.local_rotations)
    assert motion.skeleton.names[3] == "node3"


def test_a_channel_that_names_no_property_is_skipped_like_one_of_another_path(parts) -> None:
    """A channel that is no object, or whose target has no string path, animates nothing
    the reader knows: skipped, as a ``weights`` channel is; the rest of the take is read."""
    plain, _, _ = _read(*parts)
    document, binary = copy.deepcopy(parts[0]), parts[1]
    channels = document["animations"][0]["channels"]
    channels[5] = 5
    channels[6]["target"]["path"] = None
    channels[7]["target"] = "rotation"
    motion, _, _ = _read(document, binary)
    held = {5, 6, 7}  # those joints stay at rest; every other joint turns as before
    moving = [j for j in range(plain.skeleton.joint_count) if j not in held]
    np.testing.assert_array_equal(
        motion.local_rotations[:, moving], plain.local_rotations[:, moving]
    )
    assert np.ptp(motion.local_rotations[:, sorted(held)], axis=0).max() < 1e-12


def test_a_broken_animation_is_passed_over_with_a_warning_and_refused_when_asked_for() -> None:
    """A file's part that breaks the rules is that part, not the file: the other animation is
    read (and the warning names the broken one's field); asking for the broken one by name
    is refused naming it."""
    motion = read_bvh(BVH.read_bytes())
    data = multi_animation_glb({"walk": motion, "start": motion.slice_frames(0, 10)})
    document = json.loads(data[20 : 20 + int.from_bytes(data[12:16], "little")])
    binary = data[28 + int.from_bytes(data[12:16], "little") :]
    document["animations"][0]["samplers"][2]["input"] = "times"
    read, animations, chosen = _read(document, binary)
    assert chosen == "start" and read.frame_count == 10
    assert [a.name for a in animations] == ["walk", "start"]
    assert any(
        "'walk' was not read: glTF animations[0].samplers[2].input" in warning
        for warning in read.notes["warnings"]
    )
    with pytest.raises(ParseError, match=r"'walk': glTF animations\[0\]\.samplers\[2\]\.input"):
        _read(document, binary, animation="walk")


def test_a_mesh_nodes_transform_is_not_asked_only_the_skeletons(parts) -> None:
    """Only the skeleton's nodes' transforms are read: a broken one of a mesh node (not a
    joint, no animation) decides nothing."""
    plain, _, _ = _read(*parts)
    document, binary = copy.deepcopy(parts[0]), parts[1]
    document["nodes"].append({"name": "body mesh", "mesh": 0, "rotation": [0, 0, "x", 1]})
    document["scenes"][0]["nodes"].append(len(document["nodes"]) - 1)
    motion, _, _ = _read(document, binary)
    assert motion.skeleton.names == plain.skeleton.names
