"""A plain search's reads of the catalogue (app/index/catalogue.py, issue 23): a clip's row
through the per-run row table, and its heading, agree with the binary search and the full
entry, in the base, the overlay and a saved file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.index.catalogue import Catalogue
from app.index.catalogue_base import CatalogueBase
from tests.index.test_catalogue import entry


def test_rows_through_the_table_are_the_binary_searchs() -> None:
    rng = np.random.default_rng(3)
    # Runs without gaps, gaps inside a run, empty runs, an id at a run's very start.
    held = sorted({1, 2, 3, 1023, 1024, 1025, 5000, *rng.integers(6000, 60_000, 300).tolist()})
    base = CatalogueBase.build(entry(i) for i in held)
    for clip_id in [0, *held, *(i + 1 for i in held), 59_999, 70_000, 1 << 40]:
        assert base.row_of(clip_id) == base.row(clip_id), clip_id


def test_sparse_ids_fall_back_to_the_binary_search() -> None:
    held = [5, 1 << 40, (1 << 40) + 7]  # a table would need 2**30 entries
    base = CatalogueBase.build(entry(1)._replace(id=i) for i in held)
    assert base._row_table is None
    assert [base.row_of(i) for i in [5, 6, 1 << 40, (1 << 40) + 7]] == [0, -1, 1, 2]
    assert CatalogueBase.empty().row_of(1) == -1


def test_headings_are_the_entries_fields(tmp_path: Path) -> None:
    catalogue = Catalogue(tmp_path, autosave_below=0)
    catalogue.replace_all([entry(i, labels=("walk",)) for i in range(1, 40)], synced_to=1)
    catalogue.apply_changes(np.array([3, 4, 50]), {3: entry(3, name="renamed"), 50: entry(50)})
    wanted = [1, 3, 4, 39, 50, 51]
    headings = catalogue.headings(wanted)
    entries = catalogue.get_many(wanted)
    assert sorted(headings) == sorted(entries) == [1, 3, 39, 50]
    for clip_id, heading in headings.items():
        clip = entries[clip_id]
        shown = [clip.name, clip.format, clip.filenames, clip.skeleton_family, clip.labels]
        assert [tuple(f) if isinstance(f, list) else f for f in heading[:5]] == shown
        assert catalogue.get(clip_id) == clip
