"""FBX, glTF and VRM animation uploads over HTTP (real app, real readers in real worker
processes), the animation field, and BVH export of every kind of clip."""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.motion.formats import read_bvh
from tests.conftest import FIXTURES_DIR
from tests.motion.fbx_ascii import FbxNode, ascii_fbx
from tests.motion.gltf_builder import two_animation_glb
from tests.motion.test_gltf_pack import separate

FBX = ("human_ik.fbx", (FIXTURES_DIR / "ufbx_maya_human_ik_7400_binary.fbx").read_bytes())
VRMA = ("test.vrma", (FIXTURES_DIR / "three_vrm_test.vrma").read_bytes())
BVH = ("walk.bvh", (FIXTURES_DIR / "cmu_mb_02_01_first41.bvh").read_bytes())
ASF = ("02.asf", (FIXTURES_DIR / "cmu_02.asf").read_bytes())
AMC = ("02_01.amc", (FIXTURES_DIR / "cmu_02_01_first40.amc").read_bytes())


GLB = ("walk.glb", two_animation_glb(read_bvh(BVH[1])))


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(data_dir=tmp_path_factory.mktemp("scenes") / "data", parser_workers=1)
    with TestClient(create_app(settings)) as client:
        yield client


def test_an_fbx_upload_is_a_clip_listing_its_animations(live):
    response = live.post("/clips", files={"file": FBX})
    assert response.status_code in (200, 201), response.text
    clip = response.json()
    assert clip["format"] == "fbx" and clip["name"] == "human_ik"
    assert clip["animations"] == [
        {
            "name": "Take 001",
            "frame_count": 120,
            "duration": pytest.approx(120 / 24),
            "selected": True,
        }
    ]
    # The frames' cover, as the clip's own duration counts it.
    assert clip["animations"][0]["duration"] == pytest.approx(clip["duration"])
    # The same animation of the same file, named or not, is the same clip.
    again = live.post("/clips", files={"file": FBX}, data={"animation": "Take 001"})
    assert again.status_code == 200 and again.json()["id"] == clip["id"]
    assert live.get(f"/clips/{clip['id']}").json()["animations"] == clip["animations"]


def test_the_longest_animation_or_the_named_one(live):
    longest = live.post("/clips", files={"file": GLB})
    assert longest.status_code in (200, 201), longest.text
    body = longest.json()
    assert body["format"] == "gltf" and body["name"] == "walk · walk"
    assert [(a["name"], a["selected"]) for a in body["animations"]] == [
        ("walk", True),
        ("start", False),
    ]
    named = live.post("/clips", files={"file": GLB}, data={"animation": "start"})
    assert named.status_code == 201 and named.json()["name"] == "walk · start"
    assert named.json()["frame_count"] == 10
    assert named.json()["content_hash"] != body["content_hash"]
    unknown = live.post("/clips", files={"file": GLB}, data={"animation": "run"})
    assert unknown.status_code == 422
    assert "'walk', 'start'" in unknown.json()["detail"]
    on_bvh = live.post("/clips", files={"file": BVH}, data={"animation": "walk"})
    assert on_bvh.status_code == 422 and "animation" in on_bvh.json()["detail"]


def test_a_take_blender_wrote_split_over_stacks_is_one_clip_that_downloads(live):
    """Blender's per-object stacks (tests/fixtures/split_takes_fbx.py): the clip is the
    joined take, listed first and selected; its name is what the file is read by again, for
    a download as for a second upload."""
    split = ("walk.fbx", (FIXTURES_DIR / "cmu_mb_02_01_split.fbx").read_bytes())
    response = live.post("/clips", files={"file": split})
    assert response.status_code == 201, response.text
    clip = response.json()
    listed = [(a["name"], a["selected"]) for a in clip["animations"]]
    assert len(listed) == 4 and listed[0][1] and " + " in listed[0][0]
    assert clip["name"] == f"walk · {listed[0][0]}" and clip["frame_count"] == 41
    again = live.post("/clips", files={"file": split}, data={"animation": listed[0][0]})
    assert again.status_code == 200 and again.json()["id"] == clip["id"]
    download = live.get(f"/clips/{clip['id']}/file", params={"format": "bvh"})
    assert download.status_code == 200, download.text
    assert read_bvh(download.content).frame_count == 41


def test_a_vrm_animation_upload_and_an_fbx_search(live):
    response = live.post("/clips", files={"file": VRMA})
    assert response.status_code in (200, 201), response.text
    assert response.json()["format"] == "gltf"
    found = live.post("/search?k=1", files={"file": FBX})
    assert found.status_code == 200 and found.json()["query"]["format"] == "fbx"


def separate_gltf(glb: bytes, bin_name: str) -> tuple[bytes, bytes]:
    """A GLB laid out as a .gltf document and the .bin it names (Blender's "glTF Separate")."""
    document, binary = separate(glb, bin_name)
    return json.dumps(document).encode(), binary


def vectors_of(live: TestClient, clip_id: int) -> dict[str, list[float]]:
    descriptors = live.get(f"/clips/{clip_id}?include=descriptors").json()["descriptors"]
    return {name: d["vector"] for name, d in descriptors.items()}


def test_a_gltf_with_its_bin_as_another_file_field_is_the_glb_clip(live):
    document, binary = separate_gltf(VRMA[1], "test.bin")
    response = live.post(
        "/clips", files=[("file", ("test.bin", binary)), ("file", ("test.gltf", document))]
    )
    assert response.status_code == 201, response.text
    clip = response.json()
    # Stored as what it now is: one GLB (the original layout is not kept).
    assert clip["format"] == "gltf" and clip["filenames"] == ["test.glb"]
    glb = live.post("/clips", files={"file": ("packed.vrma", VRMA[1])}).json()
    assert vectors_of(live, clip["id"]) == vectors_of(live, glb["id"])
    stored = live.get(f"/clips/{clip['id']}/file")
    assert stored.status_code == 200 and stored.content[:4] == b"glTF"


def test_a_gltf_without_the_file_it_names_is_refused_naming_it(live):
    document, _ = separate_gltf(VRMA[1], "anim/test.bin")
    response = live.post("/clips", files={"file": ("test.gltf", document)})
    assert response.status_code == 422
    assert "'anim/test.bin', which was not sent" in response.json()["detail"]
    outside, binary = separate_gltf(VRMA[1], "../walk.bin")
    files = [("file", ("walk.gltf", outside)), ("file", ("walk.bin", binary))]
    response = live.post("/clips", files=files)
    assert response.status_code == 422
    assert "outside the document's folder" in response.json()["detail"]


def test_a_motion_file_with_files_it_does_not_refer_to_is_refused(live):
    response = live.post("/clips", files=[("file", BVH), ("file", ("walk.bin", b"1234"))])
    assert response.status_code == 422
    assert "more than one only for a .gltf" in response.json()["detail"]


def test_an_fbx_of_optical_markers_only_is_refused_as_markers(live):
    rng = np.random.default_rng(0)
    markers = [
        FbxNode(f"M{i}", "Marker", translation=100 * rng.uniform(0, 1.8, size=(10, 3)))
        for i in range(8)
    ]
    response = live.post("/clips", files={"file": ("capture.fbx", ascii_fbx(markers))})
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["error"] == "parse_error" and "capture.fbx" in body["detail"]
    assert "8 moving points (motion-capture markers) and no skeleton" in body["detail"]


def test_unsupported_extensions_are_listed(live):
    response = live.post("/clips", files={"file": ("walk.obj", b"x")})
    assert response.status_code == 415
    for extension in (".bvh", ".fbx", ".glb", ".gltf", ".vrma", ".vrm", ".asf", ".amc"):
        # a whole word: ".vrm" stands inside ".vrma" too
        assert re.search(rf"{re.escape(extension)}\b", response.json()["detail"]), extension


def test_a_reader_killed_mid_parse_answers_422_and_the_next_upload_works(live):
    pool = live.app.state.library.parsers
    live.post("/search?k=1", files={"file": VRMA})  # a warm worker

    def kill() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            busy = pool.busy_pids()
            if busy:
                os.kill(busy[0], signal.SIGKILL)
                return
            time.sleep(0.0005)

    killer = threading.Thread(target=kill)
    killer.start()
    response = live.post("/clips", files={"file": ("killed.fbx", FBX[1])}, data={"name": "x"})
    killer.join()
    assert response.status_code == 422, response.text
    assert response.json()["error"] == "unreadable_file"
    assert "'killed.fbx'" in response.json()["detail"]
    assert live.get("/health").json()["status"] == "ok"
    after = live.post("/search?k=1", files={"file": FBX})
    assert after.status_code == 200, after.text


@pytest.mark.parametrize(
    "files",
    [{"file": BVH}, {"skeleton": ASF, "motion": AMC}, {"file": FBX}, {"file": GLB}, {"file": VRMA}],
    ids=["bvh", "asf/amc", "fbx", "glb", "vrma"],
)
def test_bvh_export_reuploaded_is_the_clips_nearest_neighbour(live, files):
    clip = live.post("/clips", files=files).json()
    response = live.get(f"/clips/{clip['id']}/file?format=bvh")
    assert response.status_code == 200, response.text
    assert response.headers["content-disposition"].startswith("attachment;")
    assert ".bvh" in response.headers["content-disposition"]
    exported = ("export.bvh", response.content)
    vectors = live.get(f"/clips/{clip['id']}?include=descriptors").json()["descriptors"]
    for descriptor in ("posture", "kinetic", "motion"):
        found = live.post(f"/search?k=1&descriptor={descriptor}", files={"file": exported})
        hit = found.json()["results"][0]
        norm = float(np.linalg.norm(vectors[descriptor]["vector"]))
        assert hit["id"] == clip["id"], (descriptor, hit)
        assert hit["distance"] <= 1e-3 * norm, (descriptor, hit["distance"], norm)


def test_export_refuses_a_part(live):
    clip = live.post("/clips", files={"file": BVH}).json()
    response = live.get(f"/clips/{clip['id']}/file?format=bvh&part=file")
    assert response.status_code == 422
    assert live.get(f"/clips/{clip['id']}/file?format=obj").status_code == 422


@pytest.mark.parametrize(
    ("files", "params"),
    [
        ({"file": BVH}, {"format": "bvh"}),
        ({"skeleton": ASF, "motion": AMC}, {"format": "bvh"}),
        ({"file": FBX}, {"format": "bvh"}),
        ({"file": FBX}, {}),  # FBX cannot be cut as it is: the span's BVH export
        ({"file": GLB}, {}),
    ],
    ids=["bvh", "asf/amc", "fbx", "fbx-cut", "glb-cut"],
)
def test_a_span_of_any_clip_as_bvh(live, files, params):
    clip = live.post("/clips", files=files).json()
    whole = read_bvh(live.get(f"/clips/{clip['id']}/file?format=bvh").content)
    frame_time = clip["frame_time"]
    first, stop = clip["frame_count"] // 4, clip["frame_count"] * 3 // 4
    start, end = first * frame_time, stop * frame_time
    response = live.get(f"/clips/{clip['id']}/file", params={**params, "start": start, "end": end})
    assert response.status_code == 200, response.text
    assert f"{start:.2f}-{end:.2f}s.bvh" in response.headers["content-disposition"]
    cut = read_bvh(response.content)
    assert cut.frame_count == stop - first
    np.testing.assert_allclose(
        cut.local_rotations, whole.local_rotations[first:stop], atol=1e-6, rtol=0
    )
    outside = live.get(f"/clips/{clip['id']}/file", params={**params, "start": 0, "end": 999})
    assert outside.status_code == 422 and "outside the clip" in outside.json()["detail"]


def _without_animations(glb: bytes, extension: dict[str, object]) -> bytes:
    """``glb`` with its animations left out and ``extension`` added to its JSON's
    ``extensions`` (a VRM model's, which keeps the skeleton and no motion)."""
    length = int.from_bytes(glb[12:16], "little")
    document = json.loads(glb[20 : 20 + length])
    document.pop("animations", None)
    document.setdefault("extensions", {}).update(extension)
    document.setdefault("extensionsUsed", []).extend(extension)
    chunk = json.dumps(document).encode()
    chunk += b" " * (-len(chunk) % 4)
    rest = glb[20 + length :]
    body = len(chunk).to_bytes(4, "little") + b"JSON" + chunk + rest
    return b"glTF" + (2).to_bytes(4, "little") + (12 + len(body)).to_bytes(4, "little") + body


def test_a_vrm_model_is_read_as_a_glb_a_rig_and_not_a_clip(live):
    """A `.vrm` (VRoid's and VRM tools' character: a GLB with the VRM extension) sent as a
    clip is read, and refused as what it is — a rig with no animation, which POST /rigs takes
    — not as an unsupported file (415 before); sent to POST /rigs it is the rig."""
    model = ("avatar.vrm", _without_animations(GLB[1], {"VRMC_vrm": {"specVersion": "1.0"}}))
    response = live.post("/clips", files={"file": model})
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["error"] == "no_animation"
    assert "'avatar.vrm'" in body["detail"] and "rig with no animation" in body["detail"]
    assert body["detail"].endswith("it can be a rig to retarget onto (POST /rigs)")
    rig = live.post("/rigs", files={"file": model})
    assert rig.status_code == 201, rig.text
    assert rig.json()["mapping"]["joints"]["l_knee"]["joint"] == "LeftLeg"
