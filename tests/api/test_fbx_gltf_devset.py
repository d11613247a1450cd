"""Every file of ../shared/data/fbx-gltf through the real service (HTTP, parser workers).

The folder's README gives each file's kind: ``human`` files are stored and their canonical
skeleton is a sane person (upright, constant limb lengths, sides, proportions) — except one
with a skeleton and no animation, which gets a 422 saying so; ``nonhuman`` and ``malformed``
files get a clean 422; nothing ever gets a 5xx. Twins (the same motion as BVH and as FBX)
are each other's nearest neighbour under ``motion`` and agree on ``posture`` within 5 %.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.body import build_body
from app.services.parser_pool import ParserPool
from tests.api.devset import SCENE_FORMATS, check_bvh_export_round_trip, read_motion, upload_every
from tests.conftest import shared_data_dir
from tests.motion.canonical import check_canonical_body

FOLDER = shared_data_dir() / "fbx-gltf"
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not FOLDER.is_dir(), reason=f"{FOLDER} not found (set MOCAP_SHARED_DATA)"),
]

# Human figures whose rigs are not a whole humanoid skeleton by the rules of #10 (a limb is
# hip/shoulder, knee/elbow, ankle/wrist): refused with a 422 that names the limb at fault.
NOT_WHOLE_HUMANOIDS = {
    # The right arm is two joints (node18 -> node19) and the left arm's fingers branch one
    # joint below its shoulder: no arm has an elbow between shoulder and wrist.
    "khronos-samples/BrainStem.glb": "has no elbow",
    # Each arm is one bone from the lower body to the hand, each leg a zero-length hip and
    # one bone to the foot: no elbows, no knees.
    "quaternius-cc0/raylib_greenman.glb": "not a whole humanoid",
    # Two-joint limbs ending at elbow and knee (no wrists, no ankles), all four hanging from
    # one joint (body_IK).
    "sketchbook/boxman.glb": "not a whole humanoid",
}
# Twins: (BVH, FBX) of the same motion.
TWINS = [
    ("pairs-mixamo/ortiz_hiphop.bvh", "pairs-mixamo/ortiz_hiphop.fbx"),
    ("pairs-mixamo/ortiz_situp_to_idle.bvh", "pairs-mixamo/ortiz_situp_to_idle.fbx"),
    ("pairs-geno/Geno_bind.bvh", "pairs-geno/Geno_bind.fbx"),
    ("pairs-geno/Geno_stance.bvh", "pairs-geno/Geno_stance.fbx"),
    ("pairs-bvhtoolbox/walk01.bvh", "pairs-bvhtoolbox/template.fbx"),
]


def kinds() -> dict[str, str]:
    """File (relative path) -> kind, from the folder README's table."""
    if not FOLDER.is_dir():
        return {}
    table = {}
    for line in (FOLDER / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.split("|")]
        if len(cells) > 8 and cells[2].startswith("`"):
            table[cells[2].strip("`")] = cells[7]
    return table


KINDS = kinds()


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path_factory.mktemp("devset") / "data")
    with TestClient(create_app(settings)) as client:
        yield client


@pytest.fixture(scope="module")
def uploaded(live: TestClient) -> dict[str, tuple[int, dict]]:
    """Every file uploaded once: relative path -> (status, body)."""
    return upload_every(live, FOLDER, KINDS)


@pytest.fixture(scope="module")
def pool() -> Iterator[ParserPool]:
    pool = ParserPool(1)
    yield pool
    pool.close()


def test_the_readme_lists_every_file():
    on_disk = {p.relative_to(FOLDER).as_posix() for p in FOLDER.rglob("*") if p.is_file()}
    assert set(KINDS) == on_disk - {"README.md", "SOURCES.tsv"}
    assert set(KINDS.values()) == {"human", "nonhuman", "malformed"}


def test_no_answer_is_a_server_error(uploaded):
    for path, (status, body) in uploaded.items():
        assert status < 500, (path, body)
        assert status in (201, 422), (path, status, body)


@pytest.mark.parametrize("path", [p for p, k in KINDS.items() if k != "human"])
def test_non_human_and_malformed_files_are_refused(uploaded, path):
    status, body = uploaded[path]
    assert status == 422, (path, body)
    assert body["error"] in ("parse_error", "unmappable_skeleton", "unreadable_file"), body
    assert Path(path).name in body["detail"]


@pytest.mark.parametrize("path", sorted(NOT_WHOLE_HUMANOIDS))
def test_human_figures_without_whole_limbs_are_refused(uploaded, path):
    status, body = uploaded[path]
    assert status == 422, (path, body)
    assert body["error"] == "unmappable_skeleton", body
    assert Path(path).name in body["detail"] and NOT_WHOLE_HUMANOIDS[path] in body["detail"]


@pytest.mark.parametrize(
    "path", [p for p, k in KINDS.items() if k == "human" and p not in NOT_WHOLE_HUMANOIDS]
)
def test_human_files_are_people(uploaded, pool, path):
    status, body = uploaded[path]
    if "no anim" in (FOLDER / "README.md").read_text().split(f"`{path}`")[1].split("\n")[0]:
        assert status == 422 and "no animation" in body["detail"], body  # GENEA's T-pose
        return
    assert status == 201, (path, body)
    suffix = Path(path).suffix.lower()
    assert body["format"] == SCENE_FORMATS.get(suffix, "bvh")
    if suffix in SCENE_FORMATS:
        assert any(a["selected"] for a in body["animations"])
    motion = read_motion(pool, FOLDER / path)
    check_canonical_body(build_body(motion), path)


@pytest.mark.parametrize(
    "path", [p for p, k in KINDS.items() if k == "human" and p not in NOT_WHOLE_HUMANOIDS]
)
def test_a_bvh_export_re_uploaded_is_the_same_clip(live, uploaded, path):
    status, body = uploaded[path]
    if status != 201:
        pytest.skip(f"{path} is not stored ({body['detail']})")  # GENEA's rig: no animation
    check_bvh_export_round_trip(live, body["id"], path)


@pytest.fixture(scope="module")
def descriptors(live: TestClient, uploaded: dict[str, tuple[int, dict]]) -> dict[str, dict]:
    """Stored file -> its descriptors."""
    return {
        path: live.get(f"/clips/{body['id']}?include=descriptors").json()["descriptors"]
        for path, (status, body) in uploaded.items()
        if status == 201
    }


def test_twins_are_nearest_neighbours(descriptors):
    paths = sorted(descriptors)
    motion = np.array([descriptors[p]["motion"]["vector"] for p in paths])
    distances = np.linalg.norm(motion[:, None] - motion[None], axis=2)
    np.fill_diagonal(distances, np.inf)
    for bvh, fbx in TWINS:
        a, b = paths.index(bvh), paths.index(fbx)
        between = distances[a, b]
        # Ties count: Geno_stance's pose is also Geno.fbx's, at the same distance.
        assert between <= distances[a].min() + 1e-6, (bvh, between, distances[a].min())
        assert between <= distances[b].min() + 1e-6, (fbx, between, distances[b].min())


def twin(bvh: str, fbx: str) -> object:
    marks = []
    if fbx == "pairs-geno/Geno_bind.fbx":
        # The FBX's own rest pose (its nodes' default transforms, the bind pose) is not the
        # figure of the BVH's OFFSETs (the stance skeleton; the converter moved the bind
        # orientations into the rotations): the pelvis frames, found in each file's rest
        # pose, differ by 3.6 degrees, posture by 5.8 %.
        marks.append(pytest.mark.xfail(strict=True, reason="the two files' rest poses differ"))
    return pytest.param(bvh, fbx, marks=marks, id=fbx)


@pytest.mark.parametrize(("bvh", "fbx"), [twin(*pair) for pair in TWINS])
def test_twins_agree_on_posture(descriptors, bvh, fbx):
    posture_a = np.array(descriptors[bvh]["posture"]["vector"])
    posture_b = np.array(descriptors[fbx]["posture"]["vector"])
    relative = np.linalg.norm(posture_a - posture_b) / np.linalg.norm(posture_a)
    assert relative < 0.05, (bvh, fbx, relative)


def test_every_animation_counts(uploaded):
    # Files holding several animations list them all; the longest is stored by default.
    for path, (status, body) in uploaded.items():
        if status != 201 or not body.get("animations"):
            continue
        animations = body["animations"]
        chosen = next(a for a in animations if a["selected"])
        assert chosen["frame_count"] == max(a["frame_count"] for a in animations), path
        if len(animations) > 1:
            assert re.search(" · ", body["name"]), body["name"]
