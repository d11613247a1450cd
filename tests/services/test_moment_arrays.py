"""A moments search's bookkeeping over sorted ids (app/services/moment_arrays.py): numbers
kept per window id merge into id order, whatever order a round brings them in."""

from __future__ import annotations

import numpy as np

from app.services.moment_arrays import Known


def test_known_rows_merge_in_id_order_whatever_order_they_come_in() -> None:
    rng = np.random.default_rng(0)
    known = Known(2)
    every = rng.permutation(1000)[:300].astype(np.int64)
    for batch in np.array_split(every, 7):
        known.add(batch, np.stack([batch * 2.0, batch * 3.0], axis=1))
    assert np.array_equal(known.ids, np.sort(every))
    asked = np.array([every[5], 5000, every[200], -1])
    held, rows = known.find(asked)
    assert held.tolist() == [True, False, True, False]
    assert np.array_equal(rows[held], np.stack([asked[held] * 2.0, asked[held] * 3.0], axis=1))
    assert np.isnan(rows[~held]).all()
