"""Moments search on window indexes of compressed lists (``MOCAP_WINDOW_CODES=sq8``): where
every cell is scanned, the candidates re-ranked by their exact vectors give the answers of
float32 lists byte for byte — same moments, same order, same distances and similarities —
and a missing or damaged exact-vectors file is rebuilt at the next start with the same
answers. Flat indexes give the same moments too (their similarities may differ in the last
digit: a flat FAISS index measures a batch of queries in the expanded form ``|x|^2 + |y|^2 -
2 x.y``, which moves distances near zero, and the similarity scale is made of such).

Real app over HTTP, real SQLite file, real FAISS; the library is real clips (the Bandai
fixture stretched) and ``fill_synthetic`` copies of them with their windows.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from app.services.synthetic import fill_synthetic
from tests.conftest import FIXTURES_DIR
from tests.hardening.live import stretched_bvh

BANDAI = (FIXTURES_DIR / "bandai_walk_normal_001_first40.bvh").read_text()
FPS = 30
QUERIES = [(1, None, None), (3, 1.0, 4.5), (5, 2.0, 3.0), (9, None, None), (40, None, None)]


def flat(data_dir: Path) -> Settings:
    return Settings(data_dir=data_dir, index_type="flat", window_codes="float32")


def every_cell(data_dir: Path, codes: str) -> Settings:
    # Every index IVF, every cell scanned (nprobe is capped at the cells an index has).
    return Settings(data_dir=data_dir, index_type="ivf", ivf_nprobe=100_000, window_codes=codes)


def compressed(data_dir: Path) -> Settings:
    return every_cell(data_dir, "sq8")


def moments_of(found: list[bytes]) -> list[list[tuple[object, ...]]]:
    """Each answer's moments without their similarity."""
    fields = ("id", "start", "end", "distance")
    return [[tuple(m[f] for f in fields) for m in json.loads(body)["results"]] for body in found]


def answers(settings: Settings) -> list[bytes]:
    found = []
    with TestClient(create_app(settings)) as client:
        verifier = client.app.state.library.verifier  # type: ignore[attr-defined]
        if verifier is not None:  # the files mapped unchecked at start: checked, or rebuilt
            verifier.join()
        for clip, start, end in QUERIES:
            params: dict[str, object] = {"clip": clip, "k": 10, "per_clip": 2}
            if start is not None:
                params.update(start=start, end=end)
            response = client.get("/search/moments", params=params)
            assert response.status_code == 200, response.text
            assert response.json()["results"]
            found.append(response.content)
    return found


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six real clips of 8-18 s and 60 synthetic copies (~3,000 1-s windows)."""
    settings = flat(tmp_path_factory.mktemp("moments-sq8") / "data")
    with TestClient(create_app(settings)) as client:
        for n in range(6):
            body = stretched_bvh(int((8 + 2 * n) * FPS), n + 1, BANDAI)
            response = client.post("/clips", files={"file": (f"walk_{n}.bvh", body)})
            assert response.status_code == 201, response.text
    fill_synthetic(settings, 60, report=lambda _message: None)
    return settings.data_dir


def test_compressed_window_indexes_answer_byte_for_byte_like_float_ones(data_dir: Path) -> None:
    from_flat = answers(flat(data_dir))
    expected = answers(every_cell(data_dir, "float32"))
    assert moments_of(expected) == moments_of(from_flat)
    assert answers(compressed(data_dir)) == expected
    exact = sorted((data_dir / "indexes").glob("windows-*.exact.arrays"))
    assert exact, "the window indexes are IVF with compressed lists"
    # The exact vectors missing or damaged: rebuilt at the start, the same answers.
    exact[0].unlink()
    damaged = exact[-1]
    data = bytearray(damaged.read_bytes())
    data[len(data) // 2] ^= 0xFF
    damaged.write_bytes(bytes(data))
    assert answers(compressed(data_dir)) == expected
    assert exact[0].exists()
    assert answers(every_cell(data_dir, "float32")) == expected  # and back
