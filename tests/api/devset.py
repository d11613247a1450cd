"""Helpers of the dev-folder tables (tests/api/test_*_devset.py): upload every file, read
one as the service does, and check a stored clip's BVH export is the same clip again."""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient

from app.motion.formats import read_bvh
from app.motion.model import Motion, ParseLimits
from app.services.parser_pool import ParserPool

SCENE_FORMATS = {".fbx": "fbx", ".glb": "gltf", ".gltf": "gltf", ".vrma": "gltf"}


def upload_every(
    client: TestClient, folder: Path, paths: Iterable[str]
) -> dict[str, tuple[int, dict]]:
    """``POST /clips`` of each file once: relative path -> (status, JSON body)."""
    answers = {}
    for path in sorted(paths):
        data = (folder / path).read_bytes()
        response = client.post("/clips", files={"file": (Path(path).name, data)})
        answers[path] = (response.status_code, response.json())
    return answers


def read_motion(pool: ParserPool, file: Path) -> Motion:
    """The clip the service stores from ``file`` (FBX/glTF through a parser worker)."""
    data = file.read_bytes()
    kind = SCENE_FORMATS.get(file.suffix.lower())
    if kind is None:
        return read_bvh(data)
    return pool.parse(kind, data, animation=None, limits=ParseLimits()).motion


def _bvh_name(name: str) -> str:
    # The writer's renaming: a BVH joint name is one token.
    return re.sub(r"[\s{}]+", "_", name)


def check_bvh_export_round_trip(client: TestClient, clip_id: int, name: str) -> None:
    """``GET /clips/{id}/file?format=bvh`` uploaded again maps every canonical joint to the
    same joint, is not taken for a mirrored capture, and its ``motion`` vector is within
    1e-3 of the vector's length of the source's."""
    exported = client.get(f"/clips/{clip_id}/file", params={"format": "bvh"})
    assert exported.status_code == 200, exported.text
    again = client.post("/clips", files={"file": (f"{Path(name).stem}.bvh", exported.content)})
    # 200: the same bytes were stored already (two files of one rig and pose export alike).
    assert again.status_code in (200, 201), (name, again.json())
    include = {"include": "mapping,descriptors"}
    source = client.get(f"/clips/{clip_id}", params=include).json()
    copy = client.get(f"/clips/{again.json()['id']}", params=include).json()
    joints = {c: _bvh_name(j["joint"]) for c, j in source["mapping"]["joints"].items()}
    assert {c: j["joint"] for c, j in copy["mapping"]["joints"].items()} == joints, name
    assert copy["mapping"]["mirrored"] is source["mapping"]["mirrored"] is False, name
    a = np.array(source["descriptors"]["motion"]["vector"])
    b = np.array(copy["descriptors"]["motion"]["vector"])
    assert np.linalg.norm(a - b) <= 1e-3 * np.linalg.norm(a), (name, np.linalg.norm(a - b))
