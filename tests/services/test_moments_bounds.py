"""Moments search stays within its bounds whatever the query's length and ``k``.

A long take searched at the largest ``k`` placed every moment by comparing each of its
thousands of parts with every stored window near the moments: several float64 matrices of
(parts x windows), gigabytes for a ten-minute take (issue 21). Now a query has at most
``MAX_PARTS`` parts and its (parts x windows) comparisons are made a block of at most
``BLOCK_BYTES`` at a time (a query repeating itself ties most pairs: those too), and the
search still finds the take itself, placed over all of it. ``bench/bench_long_query.py``
measures the real case (a ten-minute take, 10,000 clips) on a live server.

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
from app.main import create_app
from app.services import moment_finder
from app.services.synthetic import fill_synthetic
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
    # IVF window indexes as a real library of this size has, with fewer cells than the default
    # 4 x sqrt(windows): training ~2,000 cells was two thirds of this file's CPU, and how many
    # cells there are is not what it checks.
    settings = Settings(data_dir=tmp_path_factory.mktemp("moments") / "data", ivf_nlist=256)
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
    real = moment_finder.blocks_within

    def counted(weights: Any, budget: int) -> list[slice]:
        """The real blocks, recording the bytes each one weighs."""
        found = real(weights, budget)
        blocks.extend(
            int(weights[block].sum()) if block.stop - block.start > 1 else 0 for block in found
        )
        return found

    monkeypatch.setattr(moment_finder, "blocks_within", counted)
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
    assert blocks and max(blocks) <= moment_finder.BLOCK_BYTES, blocks
    assert peak < PEAK_LIMIT, f"{peak / 2**20:.0f} MB traced during the search"


def test_blocks_stay_within_the_budget_and_cover_every_item_once() -> None:
    import numpy as np

    weights = np.array([5, 5, 5, 20, 1, 1, 1, 9, 3])
    found = moment_finder.blocks_within(weights, 10)
    assert [i for block in found for i in range(block.start, block.stop)] == list(range(9))
    for block in found:  # within the budget, or one item heavier than it alone
        assert weights[block].sum() <= 10 or block.stop - block.start == 1
    assert moment_finder.blocks_within(np.zeros(0, np.int64), 10) == []
