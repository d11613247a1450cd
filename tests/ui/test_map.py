"""GET /map: 3-MAN features from the stored kinetic vectors, PCA-2D and outliers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.motion.descriptors.kinetic import three_man
from app.motion.formats import read_asf_amc, read_bvh
from app.motion.model import Motion
from app.motion.pipeline import analyse
from app.services import library_map
from app.services.map_geometry import pca_2d, three_man_from_kinetic, three_man_many
from tests.conftest import SharedData, shared_data_dir
from tests.services.fakes import fake_motion
from tests.ui.conftest import upload_bvh

FIXTURE_MOTIONS = {
    "bandai walk (fixture)": ("bandai_walk_normal_001_first40.bvh",),
    "cmu 02_01 bvh (fixture)": ("cmu_mb_02_01_first41.bvh",),
    "cmu 02_01 asf/amc (fixture)": ("cmu_02.asf", "cmu_02_01_first40.amc"),
}
SHARED_MOTIONS = {
    "bandai walk": ("bandai-ds1/data/dataset-1_walk_normal_001.bvh",),
    "bandai dance": ("bandai-ds1/data/dataset-1_dance-short_normal_001.bvh",),
    "bandai punch": ("bandai-ds1/data/dataset-1_punch_normal_001.bvh",),
    "cmu 02_05 asf/amc": ("cmu/asf-amc/02/02.asf", "cmu/asf-amc/02/02_05.amc"),
    "cmu 131_03 bvh-max": ("cmu/bvh-max/131_03.bvh",),
}


def read(paths: list[Path]) -> Motion:
    if len(paths) == 1:
        return read_bvh(paths[0].read_bytes())
    return read_asf_amc(paths[0].read_bytes(), paths[1].read_bytes())


def check_three_man(paths: list[Path]) -> None:
    analysis = analyse(read(paths))
    stored = analysis.descriptors["kinetic"]  # float32, as the database keeps it
    assert stored.dtype == np.float32
    want = three_man(analysis.body)
    got = three_man_from_kinetic(stored)
    assert got.shape == (3,)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(three_man_many(stored[None])[0], got)


@pytest.mark.parametrize("files", FIXTURE_MOTIONS.values(), ids=FIXTURE_MOTIONS.keys())
def test_three_man_from_the_stored_kinetic_vector_equals_three_man_of_the_body(
    fixtures_dir: Path, files: tuple[str, ...]
) -> None:
    check_three_man([fixtures_dir / f for f in files])


@pytest.mark.slow
@pytest.mark.parametrize("files", SHARED_MOTIONS.values(), ids=SHARED_MOTIONS.keys())
def test_three_man_from_kinetic_on_whole_real_clips(
    shared_data: SharedData, files: tuple[str, ...]
) -> None:
    check_three_man([shared_data(f) for f in files])


POINTS: dict[str, list[float]] = {
    "a": [0, 0, 0],
    "b": [1, 0, 0],
    "c": [0, 1, 0],
    "d": [1, 1, 0.5],
    "e": [40, 30, 0],
}


def test_map_of_the_library(fake_ui_client: TestClient) -> None:
    ids = {}
    for i, (name, posture) in enumerate(POINTS.items()):
        response = fake_ui_client.post(
            "/clips",
            files={"file": (f"{name}.bvh", fake_motion(posture, kinetic=[i, 0], frames=30))},
            data={"labels": ["far" if name == "e" else "near", name]},
        )
        assert response.status_code == 201, response.text
        ids[name] = response.json()["id"]
    response = fake_ui_client.get("/map", params={"descriptor": "posture"})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["descriptor"] == "posture" and body["count"] == 5
    # The fake kinetic descriptor has 2 numbers, not FMDistance's 50: no 3-MAN.
    assert body["three_man_available"] is False
    clips = {c["name"]: c for c in body["clips"]}
    assert [c["id"] for c in body["clips"]] == sorted(ids.values())
    assert clips["a"]["labels"] == ["near", "a"] and clips["e"]["labels"] == ["far", "e"]
    assert clips["a"]["format"] == "bvh" and clips["a"]["frame_count"] == 30
    assert clips["a"]["x"] is None and clips["a"]["three_man"] is None
    want = pca_2d(np.asarray(list(POINTS.values()), dtype=np.float32)).points
    got = np.asarray([clips[n]["pca"] for n in POINTS])
    np.testing.assert_allclose(got, want, atol=1e-4)
    assert [clips[n]["outlier"] for n in POINTS] == [False, False, False, False, True]
    assert body["pca_explained_variance"][0] > 0.9
    # Another descriptor: its own PCA and outliers.
    kinetic = fake_ui_client.get("/map", params={"descriptor": "kinetic"}).json()
    assert kinetic["descriptor"] == "kinetic"
    np.testing.assert_allclose(
        [c["pca"][0] for c in kinetic["clips"]],
        pca_2d(np.array([[i, 0] for i in range(5)], float)).points[:, 0],
        atol=1e-4,
    )


def test_map_errors_and_empty_library(fake_ui_client: TestClient) -> None:
    response = fake_ui_client.get("/map", params={"descriptor": "nope"})
    assert response.status_code == 422 and response.json()["error"] == "invalid_input"
    assert "posture" in response.json()["detail"]
    empty = fake_ui_client.get("/map").json()
    assert empty["count"] == 0 and empty["clips"] == [] and empty["descriptor"] == "posture"


def test_map_3man_comes_from_the_stored_kinetic_vectors(
    ui_client: TestClient, fixtures_dir: Path
) -> None:
    names = ["bandai_walk_normal_001_first40.bvh", "cmu_mb_02_01_first41.bvh"]
    ids = [upload_bvh(ui_client, fixtures_dir / n, labels=["walk"]) for n in names]
    body = ui_client.get("/map", params={"descriptor": "kinetic"}).json()
    assert body["three_man_available"] is True
    assert body["three_man_axes"] == ["e_all", "r_u/l", "r_l/t"]
    for clip_id, name, entry in zip(ids, names, body["clips"], strict=True):
        assert entry["id"] == clip_id
        stored = ui_client.get(f"/clips/{clip_id}", params={"include": "descriptors"}).json()
        vector = np.asarray(stored["descriptors"]["kinetic"]["vector"], dtype=np.float32)
        features = three_man_from_kinetic(vector)
        np.testing.assert_allclose(entry["three_man"], features, atol=1e-5)
        assert (entry["x"], entry["y"]) == (entry["three_man"][0], entry["three_man"][1])
        body_features = three_man(analyse(read([fixtures_dir / name])).body)
        np.testing.assert_allclose(entry["three_man"], body_features, atol=1e-4)
        assert len(entry["pca"]) == 2 and entry["outlier"] is False


def test_shared_data_location_is_overridable(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOCAP_SHARED_DATA", "/somewhere/else")
    assert shared_data_dir() == Path("/somewhere/else")


def test_map_layout_is_cached_by_the_vectors(
    fake_ui_client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[int] = []
    real = library_map.vector_layout

    def counting(vectors: np.ndarray) -> library_map.Layout:
        calls.append(len(vectors))
        return real(vectors)

    monkeypatch.setattr(library_map, "vector_layout", counting)

    def add(name: str, posture: list[float]) -> None:
        response = fake_ui_client.post(
            "/clips", files={"file": (f"{name}.bvh", fake_motion(posture))}
        )
        assert response.status_code == 201

    add("a", [0, 0, 0])
    add("b", [1, 0, 0])
    first = fake_ui_client.get("/map").json()
    fake_ui_client.patch(f"/clips/{first['clips'][0]['id']}", json={"labels": ["x"]})
    again = fake_ui_client.get("/map").json()
    assert calls == [2]  # a relabelled clip does not change the vectors
    assert again["clips"][0]["labels"] == ["x"]  # ...but the answer shows its labels
    add("c", [0, 1, 0])
    assert len(fake_ui_client.get("/map").json()["clips"]) == 3
    assert calls == [2, 3]
    fake_ui_client.get("/map", params={"descriptor": "kinetic"})
    assert calls == [2, 3, 3]
