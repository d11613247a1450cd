"""Fewer lists for a query whose nearest cells are decisive: an adaptive probe (issue 23),
decided once per index file and stored beside it.

An IVF search scans the lists of the query's ``nprobe`` nearest cells; ``nprobe`` is
calibrated when the index is built (app/index/kinds.py) for the queries whose neighbours
are spread widest. Most queries' neighbours lie in the few cells nearest them: a cell whose
centroid is much farther from the query than the nearest centroid rarely holds one of its
nearest vectors. So a search skips the cells whose squared distance to the query exceeds
``cutoff`` times the nearest cell's (scale-free: a ratio, not a distance) — the lists of a
query deep inside one cell are mostly skipped, those of a query between cells are all
scanned.

**The decision** (:func:`measure_cutoff`) is a function of the index file alone, so every
worker and every start answers a search the same way: :data:`SAMPLES` stored vectors (drawn
with a fixed seed) are searched as queries, each one's ``k`` nearest in each of its
``nprobe`` cells (one FAISS call per cell rank for all), and the smallest ratio of
:data:`CUTOFFS` whose answers hold :data:`KEPT_HITS` of the full search's hits is taken —
when, counted on the same samples, it saves at least :data:`MIN_SAVED` of the numbers a
search compares (the centroids and the lists' vectors). Below that the skipping path's own
cost (a second FAISS call and the mask, ~5-7 us of a ~110 us search, bench/README.md) eats the
saving: measured with timings in an earlier version, lists skipped 6-20 % (motion, posture:
2.6-8 % of the numbers) were 2-14 % *slower*, 44-58 % (kinetic: 33-39 %) 0.69-0.77x.
None — every cell scanned, the answers bit for bit those of the full search — otherwise.

The decision is kept in ``<stem>.probe.arrays`` beside the index file (:func:`store_cutoff`),
stamped with that very file (inode, size, modification time), the settings and its own
checksum, like the locator and the cells graph: a stale, missing or damaged one is measured
again (0.1-0.6 s of CPU at a million clips), which gives the same decision — it only spares
the work.

Where: searches by clip or by file of a mapped IVF index (:class:`app.index.frozen.FrozenIVF`,
``adaptive=True``); batches (the moments' windows) and filtered searches scan every cell, and
so do indexes under :data:`MIN_CELLS` cells (the centroids' scan is most of their search) and
compressed lists (their candidates are ranked again by exact distances).

Shapes: ``samples`` ``(S, W)`` float32 (the lists' width); distances to cells ``(Q, nprobe)``.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import faiss
import numpy as np

from app.index.array_file import beside_index, read_arrays, write_arrays
from app.index.cells import GRAPH_MIN_CELLS

log = logging.getLogger(__name__)

# Ratios of squared distances tried, smallest first (4.0: a cell twice as far as the nearest).
# On stored clips' vectors the nearest cell's distance is small (a clip sits in its cell), so
# useful ratios are large: at 100,000 clips, 2.5 skipped 58 % of kinetic's 32 lists and kept
# 99.9 % of the hits (bench/README.md).
CUTOFFS = (1.5, 1.75, 2.0, 2.25, 2.5, 3.0, 3.5, 4.0)
# Share of the full search's hits the skipping search must still find: the full search's
# nprobe is calibrated to 0.995 of the exact hits (app/index/kinds.py); this loses at most a
# fifth of what is left above the 0.99.
KEPT_HITS = 0.998
# Share of a search's compared numbers the ratio must save (see the module docstring): three
# times the skipping path's own cost, so a count near the line does not decide on noise.
MIN_SAVED = 0.2
K = 10  # neighbours a sample asks for (a search's default)
# Stored vectors measured: the hits a ratio may lose are few, so many samples (one FAISS call
# per cell rank for all of them: ~0.1-0.2 s at a million clips)
SAMPLES = 500
SEED = 0  # of the samples' draw: the same vectors at every start
MIN_CELLS = GRAPH_MIN_CELLS  # fewer cells: the centroids' scan is most of a search
FORMAT = 1  # of the <index>.probe files
NONE = 0.0  # a stored ratio meaning "every cell scanned"


def skip_far_cells(to_cells: np.ndarray, cells: np.ndarray, cutoff: float) -> None:
    """Set to -1 — FAISS's search of preassigned cells skips it — each of ``cells``
    ``(Q, nprobe)`` int64 (in place) whose squared distance ``to_cells`` ``(Q, nprobe)``
    exceeds ``cutoff`` times the nearest one's (the first)."""
    cells[to_cells > to_cells[:, :1] * np.float32(cutoff)] = -1


def measure_cutoff(
    base: Any, samples: np.ndarray, nprobe: int, ids: np.ndarray
) -> tuple[float | None, dict[str, float]]:
    """The smallest of :data:`CUTOFFS` for which the IVF index ``base`` still finds
    :data:`KEPT_HITS` of its full ``nprobe``-cell answers for ``samples`` ``(S, W)`` (stored
    vectors whose ids ``(S,)`` are ``ids``, each left out of its own answer), when it saves
    :data:`MIN_SAVED` of the numbers compared; None otherwise. Also what was measured (for
    the log and the stored file): ``ratio``, ``hits_kept``, ``lists_skipped``, ``saved``."""
    count = int(samples.shape[0])
    nlist = int(base.nlist)
    if count == 0 or nprobe < 2 or nprobe > nlist:
        return None, {}
    queries = np.ascontiguousarray(samples, np.float32)
    quantizer: Any = faiss.downcast_index(base.quantizer)
    to_cells, cells = quantizer.search(queries, nprobe)
    wanted = K + 1  # the sample itself is among its nearest
    squared = np.empty((count, nprobe, wanted), np.float32)
    found = np.empty((count, nprobe, wanted), np.int64)
    one_cell: Any = faiss.SearchParametersIVF()
    one_cell.nprobe = 1
    for rank in range(nprobe):  # each sample's nearest in its rank-th cell, in one call
        keys = np.ascontiguousarray(cells[:, rank : rank + 1])
        distances = np.ascontiguousarray(to_cells[:, rank : rank + 1])
        out_squared = np.empty((count, wanted), np.float32)
        out_ids = np.empty((count, wanted), np.int64)
        base.search_preassigned_c(
            count,
            faiss.swig_ptr(queries),
            wanted,
            faiss.swig_ptr(keys),
            faiss.swig_ptr(distances),
            faiss.swig_ptr(out_squared),
            faiss.swig_ptr(out_ids),
            False,
            one_cell,
        )
        squared[:, rank], found[:, rank] = out_squared, out_ids
    own = (found == ids[:, None, None]) | (found < 0)
    squared = np.where(own, np.inf, squared)
    full = _answers(squared, found, np.ones((count, nprobe), bool))
    invlists: Any = base.invlists
    sizes = np.array([invlists.list_size(c) for c in range(nlist)], np.int64)
    probed = sizes[np.maximum(cells, 0)] * (cells >= 0)  # (S, nprobe) vectors in each list
    compared = float(probed.sum() + count * nlist)  # the lists and the centroids
    for cutoff in CUTOFFS:
        kept = cells.copy()
        skip_far_cells(to_cells, kept, cutoff)
        answers = _answers(squared, found, kept >= 0)
        hits = sum(len(a & f) for a, f in zip(answers, full, strict=True))
        share = hits / max(1, sum(len(f) for f in full))
        if share >= KEPT_HITS:
            saved = float(probed[kept < 0].sum()) / max(compared, 1.0)
            measured = {
                "ratio": cutoff,
                "hits_kept": share,
                "lists_skipped": float((kept < 0).mean()),
                "saved": saved,
            }
            return (cutoff if saved >= MIN_SAVED else None), measured
    return None, {}


def decided_cutoff(
    base: Any,
    nprobe: int,
    index_file: str | None,
    identity: list[int] | None,
    draw: Callable[[int, int], tuple[np.ndarray, np.ndarray]],
) -> float | None:
    """The decision for searches of ``nprobe`` cells of the IVF index ``base`` mapped from
    ``index_file`` (``identity``: its inode, size and modification time; None: not mapped,
    nothing stored): read from beside the file (:func:`stored_cutoff`), else measured on
    ``draw(SAMPLES, SEED)`` — the ids ``(S,)`` and vectors ``(S, W)`` of :data:`SAMPLES`
    stored vectors drawn with :data:`SEED` — and stored there."""
    if index_file is not None and identity is not None:
        stored = stored_cutoff(index_file, identity, nprobe)
        if stored is not None:
            return stored[0]
    ids, samples = draw(SAMPLES, SEED)
    cutoff, measured = measure_cutoff(base, samples, nprobe, ids)
    log.info(
        "adaptive probe of %d of %d cells: %s (%s)",
        nprobe,
        int(base.nlist),
        f"ratio {cutoff}" if cutoff is not None else "every cell",
        ", ".join(f"{key} {value:.4f}" for key, value in measured.items()) or "no ratio",
    )
    if index_file is not None and identity is not None:
        store_cutoff(index_file, identity, nprobe, cutoff, measured)
    return cutoff


def _answers(squared: np.ndarray, found: np.ndarray, kept: np.ndarray) -> list[set[int]]:
    """Each sample's :data:`K` nearest ids among the cells ``kept`` ``(S, nprobe)`` bool, from
    its per-cell nearest ``squared`` / ``found`` ``(S, nprobe, K + 1)``."""
    masked = np.where(kept[:, :, None], squared, np.inf).reshape(squared.shape[0], -1)
    flat_ids = found.reshape(found.shape[0], -1)
    order = np.argsort(masked, axis=1, kind="stable")[:, :K]
    nearest = np.take_along_axis(flat_ids, order, axis=1)
    finite = np.isfinite(np.take_along_axis(masked, order, axis=1))
    return [set(row[ok].tolist()) for row, ok in zip(nearest, finite, strict=True)]


def _cache_file(
    index_file: str, identity: list[int], nprobe: int
) -> tuple[Path, str, dict[str, Any]]:
    """Where the decision for ``index_file`` is kept (``<stem>.probe.arrays``) and its stamp:
    the file and the rule's settings."""
    settings = {
        "format": FORMAT,
        "nprobe": nprobe,
        "cutoffs": list(CUTOFFS),
        "kept_hits": KEPT_HITS,
        "min_saved": MIN_SAVED,
        "samples": SAMPLES,
        "seed": SEED,
    }
    return beside_index(index_file, "probe", identity, settings)


def stored_cutoff(
    index_file: str, identity: list[int], nprobe: int, *, lock: bool = True
) -> tuple[float | None] | None:
    """The decision kept beside ``index_file`` by any process (:func:`store_cutoff`), as a
    1-tuple (its ratio, or None: every cell scanned), when it was measured on that very file
    with these settings and matches its checksum; None when it must be measured again."""
    directory, stem, stamp = _cache_file(index_file, identity, nprobe)
    found = read_arrays(directory, stem, stamp, lock=lock)
    if isinstance(found, str):
        return None
    ratio = found[0].get("cutoff")
    if ratio is None or ratio.shape != (1,):
        return None
    value = float(ratio[0])
    if value == NONE:
        return (None,)
    return (value,) if value in CUTOFFS else None


def store_cutoff(
    index_file: str,
    identity: list[int],
    nprobe: int,
    cutoff: float | None,
    measured: dict[str, float],
    *,
    lock: bool = True,
) -> None:
    """Keep the decision ``cutoff`` for ``index_file`` (``identity`` as in
    :func:`stored_cutoff`) and what it was measured from, for every process and start."""
    directory, stem, stamp = _cache_file(index_file, identity, nprobe)
    ratio = np.array([NONE if cutoff is None else cutoff], np.float64)
    with contextlib.suppress(OSError):  # a read-only directory: measured at every start
        write_arrays(directory, stem, {"cutoff": ratio}, {**stamp, **measured}, lock=lock)
