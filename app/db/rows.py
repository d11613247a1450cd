"""What the SQL modules of ``app.db`` share: the executor they read through, chunked ``IN``
lists, bulk inserts through the driver, vectors as bytes.

Every SQL function of the service takes a :class:`~sqlalchemy.orm.Session` (or, for reads, a
Core connection) and returns plain frozen records, never ORM objects, so callers may use them
after the session is closed. Transactions are the caller's: nothing here commits.

Vectors are stored as little-endian float32 bytes; in memory they are ``(D,)`` float32 arrays,
and batches are ``(N, D)`` float32 C-contiguous with ``(N,)`` int64 ids.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from datetime import UTC, datetime
from typing import Any

import numpy as np
from sqlalchemy import Connection, func, insert, select
from sqlalchemy.orm import Session

VECTOR_DTYPE = np.dtype("<f4")

IN_CHUNK = 500  # ids per IN (...) list: far below any backend's parameter limit

Executor = Session | Connection
"""Read functions take an ORM session or a Core connection (cheaper per query: the search
path uses one connection per request)."""


def encode_vector(vector: np.ndarray) -> bytes:
    return np.ascontiguousarray(vector, dtype=VECTOR_DTYPE).tobytes()


def decode_vector(blob: bytes) -> np.ndarray:
    """``(D,)`` float32 (native byte order, writable) from stored bytes."""
    return np.frombuffer(blob, dtype=VECTOR_DTYPE).astype(np.float32)


def utc(value: datetime) -> datetime:
    # SQLite keeps no time zone; every timestamp we write is UTC.
    return value if value.tzinfo is not None else value.replace(tzinfo=UTC)


def chunks(values: Sequence[Any], size: int = IN_CHUNK) -> Iterable[Sequence[Any]]:
    for start in range(0, len(values), size):
        yield values[start : start + size]


@functools.lru_cache(maxsize=16)
def _insert_statement(table: Any, columns: tuple[str, ...], dialect: Any) -> str:
    compiled = insert(table).compile(dialect=dialect, column_keys=list(columns))
    if dialect.positional and tuple(compiled.positiontup or ()) != columns:
        raise AssertionError(f"unexpected parameter order {compiled.positiontup}")
    return str(compiled)


def insert_values(
    connection: Connection, table: Any, columns: tuple[str, ...], values: list[tuple[Any, ...]]
) -> None:
    """INSERT ``values`` (tuples in ``columns`` order, values the driver takes as they are)
    in one executemany through the driver."""
    if not values:
        return
    dialect = connection.dialect
    statement = _insert_statement(table, columns, dialect)
    params: Any = (
        values if dialect.positional else [dict(zip(columns, v, strict=True)) for v in values]
    )
    connection.exec_driver_sql(statement, params)


def vector_arrays(rows: Sequence[Any], dimension: int) -> tuple[np.ndarray, np.ndarray]:
    ids = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    data = b"".join([r[1] for r in rows])
    vectors = np.frombuffer(data, dtype=VECTOR_DTYPE).astype(np.float32).reshape(-1, dimension)
    return ids, vectors


STREAM_ROWS = 50_000  # rows a fetch when a whole table of vectors is read


def streamed_vector_arrays(
    session: Executor, query: Any, dimension: int, expected: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Like :func:`vector_arrays` for every (id, vector bytes) row of ``query`` (ordered),
    read :data:`STREAM_ROWS` rows at a time into arrays sized for ``expected`` rows (default:
    counted first; grown when more come, since the count may be stale by then). Holding
    every row first, then their bytes joined, then the floats took three copies of the
    table: ~21 GB for the 12 M one-second windows of a 1,000-hour library, ~2 GB for a
    million clips' vectors (bench/README.md). On PostgreSQL the rows come from a server-side
    cursor (``yield_per``), not the whole result at once."""
    if expected is None:
        counted = select(func.count()).select_from(query.order_by(None).subquery())
        expected = int(session.scalar(counted) or 0)
    ids = np.empty(expected, dtype=np.int64)
    vectors = np.empty((expected, dimension), dtype=np.float32)
    filled = 0
    result = session.execute(query.execution_options(yield_per=STREAM_ROWS))
    for rows in result.partitions():
        stop = filled + len(rows)
        if stop > len(ids):  # rows added since the count: grow by an eighth at least
            size = max(stop, len(ids) + len(ids) // 8)
            ids = _grown(ids, size, filled)
            vectors = _grown(vectors, size, filled)
        ids[filled:stop] = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
        data = b"".join([r[1] for r in rows])
        vectors[filled:stop] = np.frombuffer(data, dtype=VECTOR_DTYPE).reshape(-1, dimension)
        filled = stop
    return ids[:filled], vectors[:filled]


def _grown(array: np.ndarray, size: int, filled: int) -> np.ndarray:
    grown = np.empty((size, *array.shape[1:]), dtype=array.dtype)
    grown[:filled] = array[:filled]
    return grown


def select_in(session: Executor, query: Any, column: Any, ids: Iterable[int]) -> list[Any]:
    """The rows of ``query`` whose ``column`` is among ``ids``, ordered by it (in chunks)."""
    rows: list[Any] = []
    for chunk in chunks(sorted({int(i) for i in ids})):
        rows.extend(session.execute(query.where(column.in_(chunk)).order_by(column)).all())
    return rows
