"""The change feed: which clips changed since a process last looked.

Every process (each ``mocap-index serve`` replica, ``mocap-index import``) keeps its own FAISS
indexes in memory and follows the database, the source of truth, through the ``clip_changes``
table. Triggers (migration 0003) add a row there for every clip inserted or deleted and every
vector updated, in the writing transaction, so no writer can forget it. A row only says *which*
clip changed; the reader then looks the clip up (:meth:`DescriptorIndex.apply_changes`), so
applying a row twice, or rows out of order, gives the same index.

The reader's *position* is a point such that every change before it has been seen:

PostgreSQL
    Rows carry the writing transaction's id (``pg_current_xact_id()``, 64 bits, never
    reused). Ids are handed out when transactions start, not when they commit, so a row with
    a smaller id (and a smaller ``seq`` or clip id) can become visible after one with a larger
    id: following ``max(seq)`` or ``max(clip id)`` would skip it for good. Instead, before
    reading, the reader takes ``pg_snapshot_xmin(pg_current_snapshot())``: every transaction
    with a smaller id has finished, so all their rows are visible from now on. The reader
    reads the rows with ``txid >= position`` and moves its position to that xmin. Rows of
    transactions still running at that point have ``txid >= xmin`` and are read again next
    time (:class:`ChangeFeed` remembers which it has applied). This is the scheme of
    PostgreSQL's own snapshot functions (``txid_snapshot``), used by queue readers such as
    PgQ.
SQLite
    One writer at a time, and ``seq`` (AUTOINCREMENT) is handed out inside the write
    transaction, so rows commit in ``seq`` order: the position is ``max(seq) + 1`` of the
    snapshot read.

Both are read as "rows with coordinate >= position", the coordinate being ``txid`` or ``seq``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from sqlalchemy import Connection, select, text
from sqlalchemy.orm import Session

from app.db.models import ClipChange

Executor = Session | Connection


@dataclass(frozen=True, slots=True)
class Change:
    seq: int
    clip_id: int
    coordinate: int  # txid on PostgreSQL, seq on SQLite


def _is_postgres(executor: Executor) -> bool:
    bind = executor.get_bind() if isinstance(executor, Session) else executor
    return bind.dialect.name == "postgresql"


def horizon(executor: Executor) -> int:
    """The position up to which every change is visible to reads made from now on."""
    if _is_postgres(executor):
        return int(
            executor.execute(
                text("SELECT pg_snapshot_xmin(pg_current_snapshot())::text::bigint")
            ).scalar_one()
        )
    return int(
        executor.execute(text("SELECT coalesce(max(seq), 0) + 1 FROM clip_changes")).scalar_one()
    )


def latest_seq(executor: Executor) -> int:
    """The ``seq`` of the newest change row (0 when none): it moves whenever a clip is
    stored or deleted or a vector changes, in any process (a cache's version)."""
    latest = executor.execute(text("SELECT coalesce(max(seq), 0) FROM clip_changes"))
    return int(latest.scalar_one())


def read_since(executor: Executor, position: int) -> tuple[int, list[Change]]:
    """The new position and every change row at or after ``position``.

    The horizon is read first: a row of a transaction that finished before it is then visible
    to the read of the rows (PostgreSQL gives each statement a fresh snapshot; SQLite reads
    both in the transaction's one snapshot).
    """
    new_position = horizon(executor)
    coordinate = ClipChange.txid if _is_postgres(executor) else ClipChange.seq
    rows = executor.execute(
        select(ClipChange.seq, ClipChange.clip_id, coordinate)
        .where(coordinate >= position)
        .order_by(ClipChange.seq)
    ).all()
    return new_position, [Change(int(s), int(c), int(k or 0)) for s, c, k in rows]


@dataclass(frozen=True)
class Poll:
    """What one read of the feed found: the position to move to once ``clip_ids`` ``(N,)``
    int64 (sorted, unique) are applied, and the rows they came from."""

    position: int
    clip_ids: np.ndarray
    rows: Sequence[Change]


@dataclass
class ChangeFeed:
    """One process's reader of the change feed (not thread-safe: the caller serialises it).

    ``position``: every change before it has been applied. ``_applied``: rows at or after
    the position that were applied already (seq -> coordinate), so a long-running transaction
    elsewhere, which holds the position back, does not make every read apply them again.
    """

    position: int = 0
    _applied: dict[int, int] = field(default_factory=dict)

    def poll(self, executor: Executor) -> Poll:
        """The clips changed since the last poll; :meth:`advance` once they are applied."""
        new_position, rows = read_since(executor, self.position)
        fresh = [row for row in rows if row.seq not in self._applied]
        ids = np.unique(np.fromiter((r.clip_id for r in fresh), dtype=np.int64, count=len(fresh)))
        return Poll(new_position, ids, fresh)

    def advance(self, poll: Poll) -> None:
        """Record ``poll``'s rows as applied and move to its position."""
        for row in poll.rows:
            self._applied[row.seq] = row.coordinate
        self.position = max(self.position, poll.position)
        self._applied = {s: c for s, c in self._applied.items() if c >= self.position}
