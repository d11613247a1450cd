"""Write small ASCII FBX 7.4 files of animated nodes (markers, nulls, limb nodes), as the
FBX SDK lays one out: ``NodeAttribute`` + ``Model`` objects, an ``AnimationStack`` with one
layer, a curve node per animated property and a curve per axis, joined by ``Connections``.
Enough of the format for ufbx to read, and a test to say what each node is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KTIME_PER_SECOND = 46_186_158_000  # FBX time units ("KTime") in a second


@dataclass
class FbxNode:
    """One node: ``kind`` is its ``Model`` type and attribute (``"Marker"``, ``"Null"``,
    ``"LimbNode"``); ``parent`` an index into the list, or -1 for the scene root;
    ``translation`` / ``rotation`` ``(F, 3)`` keys per frame (degrees), or ``None``."""

    name: str
    kind: str
    parent: int = -1
    rest: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation: np.ndarray | None = None
    rotation: np.ndarray | None = None


def _array(name: str, values: list[str]) -> str:
    return f"\t\t{name}: *{len(values)} {{\n\t\t\ta: {','.join(values)}\n\t\t}}\n"


def ascii_fbx(nodes: list[FbxNode], *, fps: float = 30.0) -> bytes:
    """The ASCII FBX of ``nodes``, keyed at ``fps`` (every animated node the same frames)."""
    objects, connections = [], []
    next_id = iter(range(1000, 10**9, 10))
    model_ids = []
    stack, layer = next(next_id), next(next_id)
    frames = max(
        (len(k) for n in nodes for k in (n.translation, n.rotation) if k is not None), default=1
    )
    stop = round((frames - 1) / fps * KTIME_PER_SECOND)
    for node in nodes:
        attribute, model = next(next_id), next(next_id)
        model_ids.append(model)
        objects.append(
            f'\tNodeAttribute: {attribute}, "NodeAttribute::", "{node.kind}" {{\n'
            f'\t\tTypeFlags: "{"Skeleton" if node.kind == "LimbNode" else node.kind}"\n\t}}\n'
        )
        x, y, z = node.rest
        objects.append(
            f'\tModel: {model}, "Model::{node.name}", "{node.kind}" {{\n\t\tVersion: 232\n'
            f'\t\tProperties70:  {{\n\t\t\tP: "Lcl Translation", "Lcl Translation", "", "A",'
            f"{x!r},{y!r},{z!r}\n\t\t}}\n\t}}\n"
        )
        connections.append(f'\tC: "OO",{attribute},{model}\n')
    for node, model in zip(nodes, model_ids, strict=True):
        parent = 0 if node.parent < 0 else model_ids[node.parent]
        connections.append(f'\tC: "OO",{model},{parent}\n')
        for prop, keys in (("Lcl Translation", node.translation), ("Lcl Rotation", node.rotation)):
            if keys is None:
                continue
            curve_node = next(next_id)
            objects.append(
                f'\tAnimationCurveNode: {curve_node}, "AnimCurveNode::{prop[4]}", "" {{\n'
                "\t\tProperties70:  {\n"
                + "".join(f'\t\t\tP: "d|{a}", "Number", "", "A",0\n' for a in "XYZ")
                + "\t\t}\n\t}\n"
            )
            connections.append(f'\tC: "OO",{curve_node},{layer}\n')
            connections.append(f'\tC: "OP",{curve_node},{model}, "{prop}"\n')
            times = [str(round(i / fps * KTIME_PER_SECOND)) for i in range(len(keys))]
            for axis, a in enumerate("XYZ"):
                curve = next(next_id)
                objects.append(
                    f'\tAnimationCurve: {curve}, "AnimCurve::", "" {{\n\t\tDefault: 0\n'
                    "\t\tKeyVer: 4009\n"
                    + _array("KeyTime", times)
                    + _array("KeyValueFloat", [repr(float(v)) for v in keys[:, axis]])
                    + _array("KeyAttrFlags", ["24836"])
                    + _array("KeyAttrDataFloat", ["0", "0", "0", "0"])
                    + _array("KeyAttrRefCount", [str(len(keys))])
                    + "\t}\n"
                )
                connections.append(f'\tC: "OP",{curve},{curve_node}, "d|{a}"\n')
    objects.append(
        f'\tAnimationStack: {stack}, "AnimStack::Take 001", "" {{\n\t\tProperties70:  {{\n'
        f'\t\t\tP: "LocalStart", "KTime", "Time", "",0\n'
        f'\t\t\tP: "LocalStop", "KTime", "Time", "",{stop}\n\t\t}}\n\t}}\n'
        f'\tAnimationLayer: {layer}, "AnimLayer::BaseLayer", "" {{\n\t}}\n'
    )
    connections.append(f'\tC: "OO",{layer},{stack}\n')
    text = (
        "; FBX 7.4.0 project file\n"
        "FBXHeaderExtension:  {\n\tFBXHeaderVersion: 1003\n\tFBXVersion: 7400\n"
        '\tCreator: "tests/motion/fbx_ascii.py"\n}\n'
        "GlobalSettings:  {\n\tVersion: 1000\n\tProperties70:  {\n"
        '\t\tP: "UpAxis", "int", "Integer", "",1\n'
        '\t\tP: "UpAxisSign", "int", "Integer", "",1\n'
        '\t\tP: "FrontAxis", "int", "Integer", "",2\n'
        '\t\tP: "FrontAxisSign", "int", "Integer", "",1\n'
        '\t\tP: "CoordAxis", "int", "Integer", "",0\n'
        '\t\tP: "CoordAxisSign", "int", "Integer", "",1\n'
        '\t\tP: "UnitScaleFactor", "double", "Number", "",1\n'
        '\t\tP: "TimeMode", "enum", "", "",14\n'
        f'\t\tP: "CustomFrameRate", "double", "Number", "",{fps!r}\n'
        "\t}\n}\n"
        "Objects:  {\n" + "".join(objects) + "}\n"
        "Connections:  {\n" + "".join(connections) + "}\n"
        'Takes:  {\n\tCurrent: "Take 001"\n}\n'
    )
    return text.encode()
