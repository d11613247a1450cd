"""The map at scale: one layout computation per change of the library (single flight; a slow
one in the background while the last layout is served). ``bench/bench_map.py`` times 100,000
clips; the random-projection forest's neighbours are tested in test_map_geometry.py.

The layouts are computed from vectors stored in a real SQLite file through the real app
(``GET /map``); the vectors are chosen by the test (the fake motion core)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.services import library_map
from app.services.library_map import LibraryMap
from tests.services.fakes import FakeDescriber, fake_motion
from tests.ui.conftest import ui_app


@pytest.fixture
def app_client(settings: Settings) -> Iterator[TestClient]:
    # Six map requests at once from one client: more than the anonymous per-client share.
    settings = settings.model_copy(update={"max_heavy_requests_per_client": 16})
    with TestClient(ui_app(settings, FakeDescriber())) as client:
        yield client


def add(client: TestClient, name: str, posture: list[float]) -> int:
    response = client.post("/clips", files={"file": (f"{name}.bvh", fake_motion(posture))})
    assert response.status_code == 201, response.text
    clip_id: int = response.json()["id"]
    return clip_id


class HeldLayouts:
    """``compute_layout`` counted, and held until released (to force an interleaving)."""

    def __init__(self) -> None:
        self.calls = 0
        self.started = threading.Event()
        self.release = threading.Event()
        self.release.set()
        self._real = library_map.compute_layout

    def __call__(
        self, library: Any, descriptor: str, last: library_map.Layout | None = None
    ) -> library_map.Layout:
        self.calls += 1
        self.started.set()
        assert self.release.wait(30)
        return self._real(library, descriptor, last)


def test_one_computation_for_many_requests_and_none_without_a_change(
    app_client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    for i in range(4):
        add(app_client, f"c{i}", [i, 0, 0])
    held = HeldLayouts()
    held.release.clear()
    monkeypatch.setattr(library_map, "compute_layout", held)
    answers: list[Any] = []

    def ask() -> None:
        answers.append(app_client.get("/map").json())

    askers = [threading.Thread(target=ask) for _ in range(6)]
    for thread in askers:
        thread.start()
    assert held.started.wait(30)
    held.release.set()
    for thread in askers:
        thread.join(60)
    assert held.calls == 1  # six requests, one computation
    assert all(answer == answers[0] for answer in answers) and answers[0]["count"] == 4
    app_client.get("/map")
    assert held.calls == 1  # nothing changed
    add(app_client, "c4", [9, 9, 9])
    after = app_client.get("/map").json()
    assert held.calls == 2 and after["count"] == 5
    assert all(clip["pca"] is not None for clip in after["clips"])


def test_a_slow_layout_is_recomputed_in_the_background(
    app_client: TestClient, monkeypatch: pytest.MonkeyPatch
) -> None:
    for i in range(4):
        add(app_client, f"c{i}", [i, 0, 0])
    held = HeldLayouts()
    monkeypatch.setattr(library_map, "compute_layout", held)
    monkeypatch.setattr(library_map, "MAP_WAIT_SECONDS", 0.0)  # every layout counts as slow
    first = app_client.get("/map").json()
    assert held.calls == 1 and first["count"] == 4
    maps: LibraryMap = app_client.app.state.library_map  # type: ignore[attr-defined]
    maps._layouts["posture"].finished -= 3600  # long ago: may recompute at once
    held.release.clear()
    held.started.clear()
    new = add(app_client, "c4", [9, 9, 9])
    stale = app_client.get("/map").json()  # answered at once, while the layout is computed
    assert held.started.wait(30)
    assert stale == first  # the last answer
    listed = wait_for_map(app_client, lambda clips: new in clips)
    assert listed[new]["pca"] is None and listed[new]["outlier"] is False  # not laid out yet
    held.release.set()
    placed = wait_for_map(app_client, lambda clips: clips[new]["pca"] is not None)
    assert len(placed) == 5 and held.calls == 2


def wait_for_map(client: TestClient, ready: Any) -> dict[int, dict[str, Any]]:
    """The map's clips by id once ``ready(clips)`` (answers made in the background)."""
    for _ in range(600):
        clips = {clip["id"]: clip for clip in client.get("/map").json()["clips"]}
        if ready(clips):
            return clips
        threading.Event().wait(0.05)
    raise AssertionError("the map did not catch up within 30 s")
