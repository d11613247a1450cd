"""A skinned GLB laid out as Sketchfab's glTF downloads are (issue 20, docs/skeletons.md):
the scene under ``Sketchfab_model`` (Z up to Y up) -> ``model.fbx`` (turned back, scale
0.01) -> ``Object_2`` -> ``RootNode`` -> ``Armature`` (scale 100) -> ``Object_4`` -> a
created root joint added to the front of every skin, every node renamed
``<name>_<index>``. The pose is unchanged: the added transforms cancel.

    .venv/bin/python bench/sketchfab_layout.py SOURCE.glb OUT.glb

Pairs of sources and outputs go to ``bench/exporter_variants.py --pairs``.
"""

from __future__ import annotations

import json
import math
import struct
import sys
from pathlib import Path

_IDENTITY = struct.pack("<16f", 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1)


def relaid(glb: bytes) -> bytes:
    """``glb`` (one JSON and one BIN chunk) in Sketchfab's layout."""
    size = struct.unpack("<I", glb[12:16])[0]
    document = json.loads(glb[20 : 20 + size])
    blob = bytearray()
    if len(glb) > 20 + size:
        blob_size = struct.unpack("<I", glb[20 + size : 24 + size])[0]
        blob = bytearray(glb[28 + size : 28 + size + blob_size])
    nodes = document["nodes"]
    for i, node in enumerate(nodes):
        node["name"] = f"{node.get('name', 'node')}_{i:02d}"

    def add(name: str, **fields: object) -> int:
        nodes.append({"name": name, **fields})
        return len(nodes) - 1

    half = math.sqrt(0.5)
    scene = document["scenes"][document.get("scene", 0)]
    root_joint = add("GLTF_created_0_rootJoint", children=list(scene["nodes"]))
    inner = add("Object_4", children=[root_joint])
    armature = add("Armature", scale=[100.0] * 3, children=[inner])
    root = add("RootNode", children=[armature])
    holder = add("Object_2", children=[root])
    model = add("model.fbx", rotation=[half, 0, 0, half], scale=[0.01] * 3, children=[holder])
    scene["nodes"] = [add("Sketchfab_model", rotation=[-half, 0, 0, half], children=[model])]
    for skin in document.get("skins", []):
        skin["joints"] = [root_joint, *skin["joints"]]
        skin.pop("skeleton", None)
        if "inverseBindMatrices" in skin:  # the root joint's world is the identity
            accessor = document["accessors"][skin["inverseBindMatrices"]]
            view = document["bufferViews"][accessor["bufferView"]]
            start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
            matrices = _IDENTITY + bytes(blob[start : start + 64 * accessor["count"]])
            blob += b"\0" * (-len(blob) % 4)
            document["bufferViews"].append(
                {"buffer": 0, "byteOffset": len(blob), "byteLength": len(matrices)}
            )
            blob += matrices
            document["accessors"].append(
                {
                    "bufferView": len(document["bufferViews"]) - 1,
                    "componentType": 5126,
                    "count": accessor["count"] + 1,
                    "type": "MAT4",
                }
            )
            skin["inverseBindMatrices"] = len(document["accessors"]) - 1
    if document.get("buffers"):
        document["buffers"][0]["byteLength"] = len(blob)
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    body = struct.pack("<I", len(text)) + b"JSON" + text
    if blob:
        body += struct.pack("<I", len(blob)) + b"BIN\0" + bytes(blob)
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


if __name__ == "__main__":
    Path(sys.argv[2]).write_bytes(relaid(Path(sys.argv[1]).read_bytes()))
