"""A stored clip's BVH export, uploaded again, must be the same clip to the service."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from fastapi.testclient import TestClient


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
