"""Every export opened by readers that are not ours, and re-uploaded.

* Blender's own importers (bpy, in a process of their own: ``blender_reader.py``) read the
  BVH, FBX and GLB files, and ufbx (the parser pool's FBX reader) the FBX files: joint names
  and count, frame count and rate, and every joint's world position at five frames equal
  the service's own forward kinematics of the motion it wrote within 1e-3 body heights
  (after the root option and the units), for every source format (BVH, ASF/AMC, FBX, glTF,
  VRMA), every target format and each root option, on the clip's skeleton and on a rig.
* Round trip: an export (``keep`` and ``extract``), uploaded again, is its source's nearest
  neighbour under ``motion``, within 1e-3 of the vector's length.

FBX needs Blender's Python module: without it these tests skip, except in CI.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.body import build_body
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.kinematics import forward_kinematics
from app.motion.transforms import rotate
from app.services.export import ExportOptions, prepare_motion
from app.services.parser_pool import ParserPool
from app.services.rigs import get_rig, load_rig
from tests.api.exporting import (
    AMC,
    ASF,
    BANDAI,
    BVH,
    SOURCES,
    blender_read,
    five_frames,
    heads,
    need_fbx,
)

# (source, format, root, on the rig): every source and format with keep and extract, the
# in-place root on BVH, and two sources on a rig.
CASES = [
    *(
        (s, f, r, False)
        for s in SOURCES
        for f in ("bvh", "fbx", "glb")
        for r in ("keep", "extract")
    ),
    *(("bvh", f, "in-place", False) for f in ("bvh", "fbx", "glb")),
    *((s, f, "keep", True) for s in ("bvh", "fbx") for f in ("bvh", "fbx", "glb")),
    ("glb", "glb", "extract", True),
]


def case_id(case: tuple) -> str:
    source, fmt, root, on_rig = case
    return f"{source.replace('/', '-')}-to-{fmt}-{root}" + ("-rig" if on_rig else "")


@dataclass
class Export:
    source: str
    format: str
    root: str
    on_rig: bool
    clip: dict
    path: Path
    expected: np.ndarray  # (F, J, 3) world positions the service computed, reader's axes/units
    names: tuple[str, ...]
    frame_time: float
    body_height: float


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[TestClient, dict]]:
    need_fbx()
    folder = tmp_path_factory.mktemp("readers")
    settings = Settings(data_dir=folder / "data", parser_workers=1)
    with TestClient(create_app(settings)) as client:
        library = client.app.state.library  # type: ignore[attr-defined]
        rig = client.post("/rigs", files={"file": BANDAI}).json()
        loaded = load_rig(get_rig(library, rig["id"]))
        clips = {}
        for name, files in SOURCES.items():
            response = client.post("/clips", files=files)
            assert response.status_code == 201, response.text
            clips[name] = response.json()
        exports: dict[str, Export] = {}
        for case in CASES:
            source, fmt, root, on_rig = case
            clip = clips[source]
            query = {"format": fmt, "root": root, **({"rig": rig["id"]} if on_rig else {})}
            response = client.get(f"/clips/{clip['id']}/file", params=query)
            assert response.status_code == 200, (case, response.text)
            path = folder / f"{case_id(case)}.{fmt}"
            path.write_bytes(response.content)
            motion = _source_motion(source, library)
            options = ExportOptions(format=fmt, root=root, rig=rig["id"] if on_rig else None)
            prepared = prepare_motion(motion, options, loaded if on_rig else None)
            out = prepared.motion
            height = build_body(out).height
            scale = 1.0
            if fmt in ("fbx", "glb"):  # Y up, metres
                out = rotate(out, prepared.up_rotation)
                scale = prepared.metres
            _, positions = forward_kinematics(out)
            exports[case_id(case)] = Export(
                source,
                fmt,
                root,
                on_rig,
                clip,
                path,
                positions * scale,
                out.skeleton.names,
                out.frame_time,
                height * scale,
            )
        frames = {e.path: five_frames(len(e.expected)) for e in exports.values()}
        results = {}
        for fmt in ("bvh", "fbx", "glb"):
            paths = [e.path for e in exports.values() if e.format == fmt]
            wanted = sorted({f for p in paths for f in frames[p]})
            for path, result in zip(paths, blender_read(paths, wanted), strict=True):
                results[path] = result
        yield client, {"exports": exports, "blender": results, "frames": frames}


def _source_motion(source: str, library: object):
    """The clip's motion as the service reads it (FBX and glTF in a parser worker)."""
    if source == "bvh":
        return read_bvh(BVH[1])
    if source == "asf/amc":
        return read_asf_amc(ASF[1], AMC[1])
    kind = "fbx" if source == "fbx" else "gltf"
    ((_, data),) = SOURCES[source].values()
    return library.parsers.parse(
        kind, data, animation=None, limits=library.settings.parse_limits
    ).motion  # type: ignore[attr-defined]


# Seen, not explained: Blender's FBX importer reads this file's travelling top bone (the
# glTF fixture's hips, 30 m from the origin in centimetres) with its translation turned by
# a constant ~0.6 degrees, off by up to 1.4e-3 body heights after 41 frames, while ufbx
# reads the same file exactly (test_ufbx_reads_the_fbx_export) and Blender reads the BVH-
# and ASF-sourced files of the same motion right. Strict: the day it reads right, it says so.
BLENDER_FBX_OFF = {"glb-to-fbx-keep"}


def _known(cases: list[tuple], off: set[str], reason: str) -> list:
    return [
        pytest.param(c, marks=pytest.mark.xfail(strict=True, reason=reason))
        if case_id(c) in off
        else c
        for c in cases
    ]


@pytest.mark.parametrize(
    "case",
    _known(CASES, BLENDER_FBX_OFF, "Blender's FBX importer, see BLENDER_FBX_OFF"),
    ids=case_id,
)
def test_blender_reads_the_export(exported, case) -> None:
    _, state = exported
    export: Export = state["exports"][case_id(case)]
    result = state["blender"][export.path]
    assert "error" not in result, result
    names = [n for n in export.names if n in result["names"]]
    # Blender's BVH importer makes End Sites bone tails, not bones; every joint else is one.
    if export.format == "bvh":
        assert len(names) == sum(1 for n in export.names if not n.endswith("_end")) or names
        assert set(result["names"]) <= set(export.names)
    else:
        assert sorted(result["names"]) == sorted(export.names)
    assert result["fps"] == pytest.approx(1 / export.frame_time, rel=1e-4)
    keys = result["keys"]
    assert keys == len(export.expected), (keys, len(export.expected))
    index = [export.names.index(n) for n in names]
    for frame in state["frames"][export.path]:
        got = heads(result, frame, names)
        error = np.abs(got - export.expected[frame, index]).max()
        assert error <= 1e-3 * export.body_height, (frame, error, export.body_height)


@pytest.mark.parametrize("case", [c for c in CASES if c[1] == "fbx"], ids=case_id)
def test_ufbx_reads_the_fbx_export(exported, case) -> None:
    client, state = exported
    export: Export = state["exports"][case_id(case)]
    pool: ParserPool = client.app.state.library.parsers  # type: ignore[attr-defined]
    motion = pool.parse(
        "fbx", export.path.read_bytes(), animation=None, limits=Settings().parse_limits
    ).motion
    assert sorted(motion.skeleton.names) == sorted(export.names)
    assert motion.frame_count == len(export.expected)
    assert 1 / motion.frame_time == pytest.approx(1 / export.frame_time, rel=1e-4)
    _, positions = forward_kinematics(motion)
    index = [motion.skeleton.names.index(n) for n in export.names]
    for frame in state["frames"][export.path]:
        error = np.abs(positions[frame, index] - export.expected[frame]).max()
        assert error <= 1e-3 * export.body_height, (frame, error)


@pytest.mark.parametrize(
    "case",
    # (An ASF/AMC clip's FBX once sat 8.5 % away: its static transforms held the first
    # frame's pose, which a reader takes for the rest pose. They are the rest now.)
    [c for c in CASES if not c[3] and c[2] in ("keep", "extract")],
    ids=case_id,
)
def test_an_export_uploaded_again_finds_its_source(exported, case) -> None:
    client, state = exported
    export: Export = state["exports"][case_id(case)]
    clip = export.clip
    found = client.post(
        f"/search?k={len(SOURCES)}&descriptor=motion",
        files={"file": (export.path.name, export.path.read_bytes())},
    )
    assert found.status_code == 200, found.text
    hits = found.json()["results"]
    vector = client.get(f"/clips/{clip['id']}?include=descriptors").json()["descriptors"]
    norm = float(np.linalg.norm(vector["motion"]["vector"]))
    mine = next(h for h in hits if h["id"] == clip["id"])
    assert mine["distance"] <= 1e-3 * norm, (mine["distance"], norm, hits)
    # The nearest, or as near as a twin (the fixtures hold one capture in several formats).
    assert mine["distance"] <= hits[0]["distance"] + 1e-3 * norm, hits


# The BVH, ASF/AMC and glTF fixtures hold one capture (CMU 02_01): each other's twins.
TWINS = {"bvh", "asf/amc", "glb"}


@pytest.mark.parametrize("case", [c for c in CASES if c[3]], ids=case_id)
def test_a_retargeted_export_uploaded_again_finds_its_source(exported, case) -> None:
    """The CI-sized check of the retargeted round trip (the full sweep over every clip of
    ../shared/data and seven rigs is bench/eval_retarget.py, figures in docs/export.md)."""
    client, state = exported
    export: Export = state["exports"][case_id(case)]
    found = client.post(
        "/search?k=1&descriptor=motion",
        files={"file": (export.path.name, export.path.read_bytes())},
    )
    assert found.status_code == 200, found.text
    hit = found.json()["results"][0]
    sources = {e.source: e.clip["id"] for e in state["exports"].values()}
    wanted = {sources[s] for s in (TWINS if export.source in TWINS else {export.source})}
    assert hit["id"] in wanted, (hit, wanted)
