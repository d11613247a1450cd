"""Where each id of a mapped IVF file lies (the locator, app/index/locator.py) is kept in
``<index>.locator.arrays`` beside the file: a second opening reads it instead of walking the
lists and sorting every id, and a locator written from another file, damaged, or whose places
disagree with the lists is never used — it is computed again from the index file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.index import locator
from app.index.descriptor_index import DescriptorIndex
from app.index.frozen import FrozenIVF
from app.index.kinds import IndexOptions

DIMENSION = 6
COUNT = 3000


def written(directory: Path, salt: int = 0) -> Path:
    """An IVF index file of COUNT vectors (ids with gaps, ``clip << 20 | ordinal`` runs)."""
    clips = np.repeat(np.arange(1, COUNT // 10 + 1), 10)
    ids = (clips << 20) | np.tile(np.arange(10), COUNT // 10) + salt
    vectors = np.random.default_rng(salt).normal(size=(ids.size, DIMENSION)).astype(np.float32)
    index = DescriptorIndex("windows", DIMENSION, 1, directory, options=IndexOptions("ivf"))
    index.replace_all(ids.astype(np.int64), vectors, persist=True)
    return directory / "windows.faiss"


def opened_without_walking(path: Path, monkeypatch: pytest.MonkeyPatch) -> FrozenIVF:
    def walked(_base: object) -> None:
        raise AssertionError("the lists were walked: the stored locator was not used")

    with monkeypatch.context() as patch:
        patch.setattr(locator, "walk_lists", walked)
        return FrozenIVF.open(str(path))


def test_a_second_opening_reads_the_stored_locator(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = written(tmp_path)
    first = FrozenIVF.open(str(path))  # computes it (or the save's mapping did) and stores it
    assert (tmp_path / "windows.locator.arrays").exists()
    again = opened_without_walking(path, monkeypatch)
    assert np.array_equal(again.base_ids, first.base_ids)
    assert np.array_equal(again.places, first.places)
    ids = first.base_ids[::7]
    held, vectors = again.vectors(ids)
    assert held.all()
    assert np.array_equal(vectors, first.vectors(ids)[1])
    assert not again.vectors(np.array([1, (5 << 20) | 99], np.int64))[0].any()  # not held


def test_a_locator_of_another_file_is_computed_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = written(tmp_path)
    FrozenIVF.open(str(path))
    old = {p.name: p.read_bytes() for p in tmp_path.glob("windows.locator.*")}
    path = written(tmp_path, salt=1)  # the index replaced by a save: other ids, another file
    for name, data in old.items():  # ... and the old file's locator put back
        (tmp_path / name).write_bytes(data)
    with pytest.raises(AssertionError, match="walked"):
        opened_without_walking(path, monkeypatch)
    fresh = FrozenIVF.open(str(path))
    assert int(fresh.base_ids[0]) == (1 << 20) | 1
    opened_without_walking(path, monkeypatch)  # ... and stored again


@pytest.mark.parametrize("damage", ["bytes", "places", "stamp"])
def test_a_damaged_locator_is_never_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, damage: str
) -> None:
    path = written(tmp_path)
    truth = FrozenIVF.open(str(path))
    arrays, meta = tmp_path / "windows.locator.arrays", tmp_path / "windows.locator.json"
    if damage == "bytes":  # not its checksum
        data = bytearray(arrays.read_bytes())
        data[100] ^= 0xFF
        arrays.write_bytes(bytes(data))
    else:
        described = json.loads(meta.read_text())
        if damage == "stamp":  # written from another file
            described["index_file"][1] += 1
        else:  # places that do not hold their ids, with a checksum that matches
            from app.index.array_file import write_arrays

            places = truth.places.copy()
            places[[0, -1]] = places[[-1, 0]]
            stamp = {k: v for k, v in described.items() if k in ("format", "index_file")}
            write_arrays(
                tmp_path, "windows.locator", {"ids": truth.base_ids, "places": places}, stamp
            )
            described = json.loads(meta.read_text())
        meta.write_text(json.dumps(described))
    with pytest.raises(AssertionError, match="walked"):
        opened_without_walking(path, monkeypatch)
    reopened = FrozenIVF.open(str(path))
    assert np.array_equal(reopened.places, truth.places)
