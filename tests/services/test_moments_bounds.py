"""Moments search stays within its bounds whatever the query's length and ``k``.

A long take searched at the largest ``k`` placed every moment by comparing each of its
thousands of parts with every stored window near the moments: several float64 matrices of
(parts x windows), gigabytes for a ten-minute take (issue 21). Now a search compares at most
``MAX_PAIRS_PER_SEARCH`` pairs, a block of ``MAX_PAIRS_PER_BLOCK`` at a time, and still
finds the take itself, placed over all of it. ``bench/bench_long_query.py`` measures the real
case (a ten-minute take, 10,000 clips) on a live server.

Real app over HTTP, real SQLite file, real FAISS indexes; the library is real clips (the
Bandai fixture played back and forth: one walk, so every clip matches the take somewhere) and
``fill_synthetic`` copies of them with their windows.
"""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.importer import fill_synthetic
from app.main import create_app
from app.services import moments
from tests.conftest import FIXTURES_DIR
from tests.hardening.live import stretched_bvh

BANDAI = (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_text()
FPS = 30
TAKE_SECONDS = 180
PEAK_LIMIT = 400 * 2**20  # bytes traced while one search runs


def bandai(seconds: float, n: int) -> bytes:
    return stretched_bvh(int(seconds * FPS), n, BANDAI)


@pytest.fixture(scope="module")
def library_dir(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Settings, int]]:
    """Eight real clips of 20-55 s, a three-minute take, and synthetic copies: 400 clips."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("moments") / "data")
    with TestClient(create_app(settings)) as client:
        for n in range(8):
            files = {"file": (f"walk_{n}.bvh", bandai(20 + 5 * n, n + 1))}
            assert client.post("/clips", files=files).status_code == 201
        take = client.post("/clips", files={"file": ("take.bvh", bandai(TAKE_SECONDS, 0))})
        assert take.status_code == 201, take.text
    fill_synthetic(settings, 400, report=lambda _message: None)
    yield settings, int(take.json()["id"])


def search_take(client: TestClient, **params: Any) -> list[dict[str, Any]]:
    response = client.post(
        "/search/moments",
        params={"k": 1000, "per_clip": 1000, **params},
        files={"file": ("take.bvh", bandai(TAKE_SECONDS, 0))},
    )
    assert response.status_code == 200, response.text
    results: list[dict[str, Any]] = response.json()["results"]
    return results


def test_a_long_take_at_the_largest_k_is_placed_within_the_bounds(
    library_dir: tuple[Settings, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    settings, take_id = library_dir
    blocks: list[int] = []
    real = moments._aligned_starts

    def counted(
        library: Any,
        groups: Any,
        frame_times: Any,
        parts: Any,
        descriptor: str,
        seconds: float,
        exclude: Any,
    ) -> Any:
        """The real placing, counting the (part, window) pairs each block compares."""
        name = moments.window_index_name(descriptor, parts.length)
        near = moments._windows_near(library, name, groups, frame_times, seconds, exclude)
        blocks.append(len(parts.offsets) * int(near[2].sum()))
        return real(library, groups, frame_times, parts, descriptor, seconds, exclude)

    monkeypatch.setattr(moments, "_aligned_starts", counted)
    with TestClient(create_app(settings)) as client:
        tracemalloc.start()
        try:
            results = search_take(client)
            _, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    assert len(results) > 100
    assert results[0]["distance"] < 0.05  # the walk the take is made of, stored
    (take,) = [moment for moment in results if moment["id"] == take_id]
    assert take["start"] == pytest.approx(0, abs=1.0)
    assert take["end"] == pytest.approx(TAKE_SECONDS, abs=1.0)
    assert blocks and max(blocks) <= moments.MAX_PAIRS_PER_BLOCK, blocks
    assert sum(blocks) <= moments.MAX_PAIRS_PER_SEARCH, blocks
    assert peak < PEAK_LIMIT, f"{peak / 2**20:.0f} MB traced during the search"


def test_parts_are_thinned_evenly_keeping_both_ends() -> None:
    import numpy as np

    parts = moments.Parts(8.0, np.arange(1000) / 30, np.zeros((1000, 3), np.float32))
    thinned = moments._thinned(parts, 100)
    assert len(thinned.offsets) == 100
    assert thinned.offsets[0] == 0 and thinned.offsets[-1] == parts.offsets[-1]
    steps = np.diff(thinned.offsets)
    assert steps.max() - steps.min() <= 1 / 30 + 1e-9
    assert moments._thinned(parts, 2000) is parts
