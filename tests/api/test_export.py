"""Downloads with format, units, fps, root and rig; rigs; many clips as a ZIP; the CLI."""

from __future__ import annotations

import csv
import io
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.cli import main
from app.config import Settings
from app.main import create_app
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.formats.bvh_writer import write_bvh
from app.motion.formats.gltf import read_gltf
from app.motion.kinematics import forward_kinematics
from app.services.export_pool import fbx_unavailable_reason
from tests.api.exporting import (
    AMC,
    ASF,
    BANDAI,
    BVH,
    GLB,
    SOURCES,
    frames_zero,
    without_animation,
)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    data = tmp_path_factory.mktemp("exports") / "data"
    settings = Settings(data_dir=data, parser_workers=1, max_export_clips=4)
    with TestClient(create_app(settings)) as client:
        client.app_data_dir = data  # type: ignore[attr-defined]
        yield client


@pytest.fixture(scope="module")
def clips(live: TestClient) -> dict[str, dict]:
    out = {}
    for name in ("bvh", "asf/amc", "glb"):
        response = live.post("/clips", files=SOURCES[name], data={"labels": "walk"})
        assert response.status_code == 201, response.text
        out[name] = response.json()
    return out


@pytest.fixture(scope="module")
def rig(live: TestClient) -> dict:
    response = live.post("/rigs", files={"file": BANDAI})
    assert response.status_code == 201, response.text
    return response.json()


@pytest.mark.parametrize("source", ["bvh", "asf/amc"])
def test_bvh_of_a_bvh_or_asf_clip_is_todays_export_byte_for_byte(live, clips, source) -> None:
    clip = clips[source]
    motion = read_bvh(BVH[1]) if source == "bvh" else read_asf_amc(ASF[1], AMC[1])
    expected = write_bvh(motion).encode()
    for query in ("format=bvh", "format=bvh&root=keep"):
        response = live.get(f"/clips/{clip['id']}/file?{query}")
        assert response.status_code == 200, response.text
        assert response.content == expected, query


@pytest.mark.parametrize(
    ("query", "named"),
    [
        ("units=cm", "units"),
        ("rig=1", "rig"),
        ("format=bvh&fps=0", "fps"),
        ("format=bvh&fps=100000", "fps"),
        ("format=bvh&root=sideways", "root"),
        ("format=obj", "format"),
        ("format=glb&units=cm", "units"),
        ("format=bvh&rig=999", "rig"),
        ("format=glb&part=file", "part"),
    ],
)
def test_a_bad_option_is_named(live, clips, query, named) -> None:
    response = live.get(f"/clips/{clips['bvh']['id']}/file?{query}")
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["error"] == "invalid_input"
    assert named in body["detail"], body


def test_fps_units_and_root_end_up_in_the_file(live, clips) -> None:
    clip = clips["bvh"]
    base = f"/clips/{clip['id']}/file?format=bvh"
    metres = read_bvh(live.get(f"{base}&units=m&fps=30&root=in-place").content)
    inches = read_bvh(live.get(f"{base}&units=in&fps=30&root=in-place").content)
    assert metres.frame_time == pytest.approx(1 / 30)
    assert metres.frame_count == 11  # 40 frames' span at 30 fps, first and last kept
    _, in_m = forward_kinematics(metres)
    _, in_in = forward_kinematics(inches)
    np.testing.assert_allclose(in_m, in_in * 0.0254, atol=1e-6)
    height = float(np.ptp(in_m[0], axis=0).max())
    assert 1.2 < height < 2.2  # a person, in metres
    assert np.abs(metres.root_translation[:, [0, 2]]).max() <= 1e-6 * height


def test_glb_on_a_rig_has_the_rigs_skeleton(live, clips, rig) -> None:
    response = live.get(f"/clips/{clips['bvh']['id']}/file?format=glb&rig={rig['id']}&root=extract")
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "model/gltf-binary"
    motion, _, _ = read_gltf(response.content)
    bandai = read_bvh(BANDAI[1])
    assert motion.skeleton.names[0] == "root"
    assert set(motion.skeleton.names[1:]) == set(bandai.skeleton.names)
    assert motion.frame_count == clips["bvh"]["frame_count"]


def test_a_span_on_a_rig(live, clips, rig) -> None:
    clip = clips["asf/amc"]
    start, end = 5 * clip["frame_time"], 25 * clip["frame_time"]
    response = live.get(
        f"/clips/{clip['id']}/file",
        params={"format": "bvh", "rig": rig["id"], "start": start, "end": end},
    )
    assert response.status_code == 200, response.text
    assert read_bvh(response.content).frame_count == 20
    assert f"{start:.2f}-{end:.2f}s.bvh" in response.headers["content-disposition"]


def test_fbx_without_blender_answers_501(live, clips) -> None:
    reason = fbx_unavailable_reason()
    if reason is None:
        pytest.skip("Blender's Python module is installed here: FBX is written (the FBX tests)")
    response = live.get(f"/clips/{clips['bvh']['id']}/file?format=fbx")
    assert response.status_code == 501
    assert response.json()["error"] == "fbx_unavailable"


# -- rigs ----------------------------------------------------------------------------------


@pytest.fixture
def rig_client(settings: Settings) -> Iterator[TestClient]:
    """The real app on SQLite and on PostgreSQL (the ``settings`` fixture's two runs)."""
    with TestClient(create_app(settings)) as client:
        yield client


def test_rigs_are_stored_listed_read_and_deleted(rig_client: TestClient) -> None:
    client = rig_client
    created = client.post("/rigs", files={"file": BANDAI}, data={"name": "Bandai actor"})
    assert created.status_code == 201, created.text
    rig = created.json()
    assert created.headers["location"] == f"/rigs/{rig['id']}"
    assert rig["name"] == "Bandai actor" and rig["format"] == "bvh" and rig["units"] == "cm"
    assert set(rig["mapping"]) == {"joints", "end_sites", "pose", "mirrored"}
    assert rig["mapping"]["joints"]["l_hip"]["joint"] == "UpperLeg_L"
    assert len(rig["skeleton"]["positions"]) == rig["joint_count"]
    # The mapping has the shape of a clip's ?include=mapping.
    clip = client.post("/clips", files={"file": BANDAI}).json()
    clip_mapping = client.get(f"/clips/{clip['id']}?include=mapping").json()["mapping"]
    assert set(clip_mapping) == set(rig["mapping"])
    assert set(clip_mapping["joints"]) == set(rig["mapping"]["joints"])

    from_clip = client.post(f"/rigs?from_clip={clip['id']}")
    assert from_clip.status_code == 201, from_clip.text
    listed = client.get("/rigs").json()
    assert listed["total"] == 2
    assert [r["id"] for r in listed["items"]] == [rig["id"], from_clip.json()["id"]]
    assert "mapping" not in listed["items"][0]
    assert client.get(f"/rigs/{rig['id']}").json()["mapping"] == rig["mapping"]
    assert client.delete(f"/rigs/{rig['id']}").status_code == 204
    assert client.get(f"/rigs/{rig['id']}").status_code == 404
    assert client.delete(f"/rigs/{rig['id']}").status_code == 404
    assert client.get("/rigs").json()["total"] == 1


def test_a_file_without_motion_is_a_rig(live: TestClient) -> None:
    template = ("template.bvh", frames_zero(BVH[1]))
    assert live.post("/clips", files={"file": template}).status_code == 422
    rig = live.post("/rigs", files={"file": template})
    assert rig.status_code == 201, rig.text
    # A skeleton exported alone: the hierarchy and no MOTION section at all.
    hierarchy_only = ("skeleton.bvh", frames_zero(BVH[1]).split(b"MOTION")[0])
    assert live.post("/clips", files={"file": hierarchy_only}).status_code == 422
    alone = live.post("/rigs", files={"file": hierarchy_only})
    assert alone.status_code == 201, alone.text
    assert alone.json()["mapping"] == rig.json()["mapping"]
    character = ("character.glb", without_animation(GLB[1]))
    rig = live.post("/rigs", files={"file": character})
    assert rig.status_code == 201, rig.text
    assert rig.json()["format"] == "gltf" and rig.json()["units"] == "cm"
    skeleton_only = live.post("/rigs", files={"file": ASF})
    assert skeleton_only.status_code == 201, skeleton_only.text


def test_a_character_as_gltf_with_its_bin_is_a_rig(live: TestClient) -> None:
    from tests.api.test_scene_uploads import separate_gltf

    document, binary = separate_gltf(without_animation(GLB[1]), "character.bin")
    files = [("file", ("character.bin", binary)), ("file", ("character.gltf", document))]
    rig = live.post("/rigs", files=files)
    assert rig.status_code == 201, rig.text
    glb = live.post("/rigs", files={"file": ("character.glb", without_animation(GLB[1]))})
    assert rig.json()["mapping"] == glb.json()["mapping"]
    alone = live.post("/rigs", files={"file": ("character.gltf", document)})
    assert alone.status_code == 422
    assert "'character.bin', which was not sent" in alone.json()["detail"]


@pytest.mark.parametrize(
    ("files", "status", "code"),
    [
        ({"file": ("notes.txt", b"hello")}, 415, "unsupported_media_type"),
        ({"file": ("empty.bvh", b"")}, 422, "invalid_input"),
        ({"file": ("broken.bvh", b"HIERARCHY\nROOT x\n{\n")}, 422, "parse_error"),
        ({"file": ("broken.glb", b"glTF\x02\x00\x00\x00")}, 422, "parse_error"),
    ],
)
def test_a_bad_rig_file_is_refused(live, files, status, code) -> None:
    response = live.post("/rigs", files=files)
    assert response.status_code == status, response.text
    assert response.json()["error"] == code


def test_a_skeleton_that_is_not_a_person_is_refused(live) -> None:
    chain = (
        "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Zrotation Xrotation Yrotation\n"
        " JOINT b\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
        "  End Site\n  {\n   OFFSET 0 10 0\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n"
        "0 0 0 0 0 0\n"
    )
    response = live.post("/rigs", files={"file": ("chain.bvh", chain.encode())})
    assert response.status_code == 422
    assert response.json()["error"] == "unmappable_skeleton"


def test_writing_rigs_needs_the_key(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", api_key="secret")
    with TestClient(create_app(settings)) as client:
        assert client.post("/rigs", files={"file": BANDAI}).status_code == 401
        headers = {"Authorization": "Bearer secret"}
        created = client.post("/rigs", files={"file": BANDAI}, headers=headers)
        assert created.status_code == 201
        assert client.get("/rigs").status_code == 200
        assert client.delete(f"/rigs/{created.json()['id']}").status_code == 401


# -- many clips ----------------------------------------------------------------------------


def unzip(content: bytes) -> tuple[dict[str, bytes], list[dict[str, str]]]:
    archive = zipfile.ZipFile(io.BytesIO(content))
    files = {name: archive.read(name) for name in archive.namelist()}
    rows = list(csv.DictReader(io.StringIO(files.pop("manifest.csv").decode())))
    return files, rows


def test_many_clips_as_one_zip_with_a_manifest(live, clips, rig) -> None:
    bvh = clips["bvh"]
    body = {
        "clips": [bvh["id"], clips["glb"]["id"], {"id": bvh["id"], "start": 0.05, "end": 0.2}],
        "format": "glb",
        "rig": rig["id"],
        "root": "in-place",
    }
    response = live.post("/exports", json=body)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/zip"
    files, rows = unzip(response.content)
    assert sorted(files) == sorted(["walk.glb", "walk (2).glb", f"{clips['glb']['name']}.glb"])
    assert [int(r["id"]) for r in rows] == [bvh["id"], clips["glb"]["id"], bvh["id"]]
    assert list(rows[0]) == [
        "id",
        "name",
        "file",
        "source",
        "licence",
        "frames",
        "fps",
        "duration",
        "options",
        "error",
    ]
    assert rows[0]["options"] == f"format=glb root=in-place rig={rig['id']}"
    assert int(rows[2]["frames"]) == round(0.15 * 120)
    for row in rows:
        motion, _, _ = read_gltf(files[row["file"]])
        assert motion.frame_count == int(row["frames"])


def test_by_label_and_by_search(live, clips) -> None:
    by_label = live.post("/exports", json={"label": ["walk"], "format": "bvh"})
    assert by_label.status_code == 200, by_label.text
    files, rows = unzip(by_label.content)
    assert len(rows) == len(files) == 3
    search = {"search": {"clip": clips["bvh"]["id"], "k": 2}, "format": "bvh"}
    by_search = live.post("/exports", json=search)
    assert by_search.status_code == 200, by_search.text
    _, rows = unzip(by_search.content)
    assert len(rows) == 2 and clips["bvh"]["id"] not in [int(r["id"]) for r in rows]


def test_too_many_clips_or_none_is_422(live, clips) -> None:
    many = live.post("/exports", json={"clips": [clips["bvh"]["id"]] * 5})
    assert many.status_code == 422
    assert "5 clips, more than the limit of 4" in many.json()["detail"]
    assert "MOCAP_MAX_EXPORT_CLIPS" in many.json()["detail"]
    both = live.post("/exports", json={"clips": [1], "label": ["walk"]})
    assert both.status_code == 422 and "exactly one" in both.json()["detail"]
    unknown = live.post("/exports", json={"clips": [99999]})
    assert unknown.status_code == 404
    # Past signed 64 bits no database can even be asked (schemathesis found it: a 500).
    for huge in (13161610185593134776320, 2**63, -18573, 0):
        answer = live.post("/exports", json={"clips": [clips["bvh"]["id"], {"id": huge}]})
        assert answer.status_code == 404, (huge, answer.text)
        assert f"no clip with id {huge}" in answer.json()["detail"]
    bad = live.post(
        "/exports", json={"clips": [clips["bvh"]["id"]], "format": "glb", "units": "cm"}
    )
    assert bad.status_code == 422 and bad.json()["detail"].startswith("units:")
    # An empty label filter names no clip: said of an export, not of a delete (it was).
    for labels in ([], [""], [" , "]):
        empty = live.post("/exports", json={"label": labels})
        assert empty.status_code == 422, (labels, empty.text)
        assert empty.json()["detail"].endswith("of the clips to export"), empty.text


def test_the_export_command_writes_a_folder(live, clips, rig, tmp_path, capsys) -> None:
    data_dir = live.app_data_dir  # type: ignore[attr-defined]
    out = tmp_path / "out"
    code = main(
        [
            "export",
            "--data-dir",
            str(data_dir),
            "--clip",
            str(clips["bvh"]["id"]),
            str(clips["asf/amc"]["id"]),
            "--format",
            "bvh",
            "--rig",
            str(rig["id"]),
            "--root",
            "in-place",
            "--units",
            "cm",
            "--fps",
            "30",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert code == 0, capsys.readouterr()
    written = sorted(p.name for p in out.iterdir())
    assert written == sorted(["walk.bvh", f"{clips['asf/amc']['name']}.bvh", "manifest.csv"])
    motion = read_bvh((out / "walk.bvh").read_bytes())
    assert motion.frame_time == pytest.approx(1 / 30)
    assert motion.skeleton.names == read_bvh(BANDAI[1]).skeleton.names
    assert "wrote 2 files" in capsys.readouterr().out
