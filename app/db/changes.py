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
    transaction, so rows commit in ``seq`` order: the position is the next ``seq`` of the
    snapshot read (``max(seq) + 1``, kept by ``sqlite_sequence`` once rows are pruned).

Both are read as "rows with coordinate >= position", the coordinate being ``txid`` or ``seq``.

Retention (:func:`prune`): every server records now and then a *mark* (``clip_change_marks``:
the horizon and the time). The rows before the newest mark older than the retention are
deleted and that mark is flagged ``pruned``. A mark is a past horizon, so no transaction can
still add a row below it. A reader whose position is before :func:`pruned_before` (a replica
or an index file that was away longer than the retention) may have missed changes: it
rebuilds its indexes from the database instead (``app.services.library``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta

import numpy as np
from sqlalchemy import Connection, delete, func, select, text, update
from sqlalchemy.orm import Session

from app.db.models import ClipChange, ClipChangeMark

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
    # The next seq AUTOINCREMENT hands out: past every row ever written, also once pruning
    # has deleted them all (max(seq) would go back then).
    return int(
        executor.execute(
            text(
                "SELECT max(coalesce((SELECT seq FROM sqlite_sequence WHERE name = "
                "'clip_changes'), 0), coalesce((SELECT max(seq) FROM clip_changes), 0)) + 1"
            )
        ).scalar_one()
    )


def latest_seq(executor: Executor) -> int:
    """The ``seq`` of the newest change row (0 when none): it moves whenever a clip is
    stored or deleted or a vector changes, in any process (a cache's version)."""
    latest = executor.execute(text("SELECT coalesce(max(seq), 0) FROM clip_changes"))
    return int(latest.scalar_one())


def pruned_before(executor: Executor) -> int:
    """The position before which change rows were deleted (0: none ever were)."""
    found = executor.execute(
        select(func.max(ClipChangeMark.position)).where(ClipChangeMark.pruned)
    ).scalar_one()
    return int(found or 0)


def prune(session: Session, retention: timedelta, *, now: datetime | None = None) -> int:
    """Record a mark at the current horizon, then delete the change rows before the newest
    mark recorded at least ``retention`` ago (and the older marks); returns how many rows
    went. Run it in a write transaction (SQLite: the write lock, so the horizon is exact)."""
    now = now if now is not None else datetime.now(UTC)
    position = horizon(session)
    if session.get(ClipChangeMark, position) is None:
        session.add(ClipChangeMark(position=position, recorded_at=now, pruned=False))
        session.flush()
    cutoff = now - retention
    mark = session.execute(
        select(func.max(ClipChangeMark.position)).where(ClipChangeMark.recorded_at <= cutoff)
    ).scalar_one()
    if mark is None or int(mark) <= pruned_before(session):
        return 0
    coordinate = ClipChange.txid if _is_postgres(session) else ClipChange.seq
    removed = session.execute(delete(ClipChange).where(coordinate < mark))
    session.execute(delete(ClipChangeMark).where(ClipChangeMark.position < mark))
    session.execute(
        update(ClipChangeMark).where(ClipChangeMark.position == mark).values(pruned=True)
    )
    return int(removed.rowcount or 0)  # type: ignore[attr-defined]


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
