"""Uploaded files, kept content-addressed (by the sha256 of their bytes), in one of two stores
behind one interface, :class:`BlobStore`:

:class:`FileBlobStore` (SQLite)
    ``<root>/<sha256[:2]>/<sha256>`` files beside the database file: one machine.
:class:`DatabaseBlobStore` (PostgreSQL)
    rows of the ``blobs`` table, so every replica, on any machine, needs nothing but the
    database URL, and a database backup holds the files too.

Identical bytes are stored once (a CMU skeleton shared by many motions, say); the database's
``clip_files`` rows say which clips use a file, and the service deletes a file only when no
clip refers to it any more. Files are stored (and committed) before the clip rows that name
them; those a crash left without a clip are removed by :meth:`BlobStore.remove_unreferenced`.

Several processes share one store (replicas, ``serve --workers N``, an import beside the
server), so a file one of them finds already stored may be removed by another — deleting the
last clip that used it — before the first commits its clip against it. Removing and claiming
are therefore both done inside a database write transaction, which orders them:

* :meth:`BlobStore.claim`, in the transaction that inserts the clips, writes again any of
  their files that is gone and keeps them until the commit;
* :meth:`BlobStore.release` (after a delete, or a failed store) and
  :meth:`BlobStore.remove_unreferenced` remove a file only while holding it against claims and
  seeing every committed clip that refers to it.

On SQLite the transaction's write lock (``BEGIN IMMEDIATE``, one writer for every process)
orders them; on PostgreSQL row locks on ``blobs`` do: a claim holds its rows ``FOR SHARE``, a
removal takes them ``FOR UPDATE`` (waiting for the claimer's commit) and then looks for
references in a new statement, which sees that commit.

Paths come from sha256 hex digests only (:meth:`FileBlobStore.path` refuses anything else): a
file name a user uploads is kept in the database as text and never becomes a path.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

from sqlalchemy import Engine, Exists, Select, delete, exists, select
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session

from app.db import clips as clip_db
from app.db.models import Blob, ClipFile
from app.db.rows import IN_CHUNK
from app.errors import StorageUnavailable

_SHA256 = re.compile(r"[0-9a-f]{64}")


def _check_sha256(sha256: str) -> str:
    if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
        raise ValueError(f"not a sha256 hex digest: {sha256!r}")
    return sha256


class BlobStore(Protocol):
    """Where uploaded files are kept; every file is named by the sha256 of its bytes."""

    def put(self, data: bytes) -> tuple[str, bool]:
        """Store ``data`` durably; returns its sha256 and whether it was not stored before."""
        ...

    def put_many(self, files: Sequence[tuple[bytes, str]]) -> list[tuple[str, bool]]:
        """Store ``(data, sha256 of data)`` pairs durably, all or none (what :meth:`put` does
        for one); returns, in order, each sha256 and whether it was not stored before."""
        ...

    def read(self, sha256: str) -> bytes:
        """The stored bytes (:class:`StorageUnavailable` when they cannot be read)."""
        ...

    def exists(self, sha256: str) -> bool: ...

    def delete(self, sha256: str) -> None:
        """Remove a file (the caller checked, under :meth:`release`'s rules, that no clip
        refers to it)."""
        ...

    def claim(self, session: Session, files: Sequence[tuple[bytes, str]]) -> list[str]:
        """In ``session``, the write transaction inserting the clips that name ``files``
        (``(data, sha256 of data)`` pairs): store again any file removed since it was put,
        and keep them all until the transaction ends; returns the sha256s written again."""
        ...

    def release(self, session: Session, shas: Iterable[str]) -> int:
        """In ``session``, a write transaction: remove the files of ``shas`` no clip refers
        to (none that a concurrent :meth:`claim` holds); returns how many went."""
        ...

    def remove_unreferenced(self, session: Session, *, older_than: float) -> int:
        """In ``session``, a write transaction: remove the files no clip refers to and any
        half-written ones, last written before ``older_than`` (a ``time.time()`` value);
        returns how many went."""
        ...


class FileBlobStore:
    """Files under ``root`` (SQLite deployments: one machine)."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def path(self, sha256: str) -> Path:
        return self.root / sha256[:2] / _check_sha256(sha256)

    def put(self, data: bytes) -> tuple[str, bool]:
        """Store ``data``; returns its sha256 and whether a new file was written."""
        return self._put_one(data, hashlib.sha256(data).hexdigest())

    def _put_one(self, data: bytes, sha: str) -> tuple[str, bool]:
        path = self.path(sha)
        if path.is_file():
            return sha, False
        tmp = path.with_name(f".{sha}.{os.getpid()}.{threading.get_ident()}.tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)  # readers never see a half-written file
        except OSError as exc:
            raise StorageUnavailable(f"cannot store the uploaded file: {exc.strerror}") from exc
        finally:
            # Not there any more once renamed; cleaning up must not hide the real error.
            with contextlib.suppress(OSError):
                tmp.unlink(missing_ok=True)
        return sha, True

    def put_many(self, files: Sequence[tuple[bytes, str]]) -> list[tuple[str, bool]]:
        """:meth:`put` for many ``(data, sha256 of data)`` files, all or none: the new files
        are written under temporary names, fsynced together (a few threads: the file system
        commits concurrent fsyncs together) and renamed, as :meth:`put` does one by one.
        Only this call's files are waited for: ``syncfs`` would also wait for whatever else
        the machine wrote (0.2 s instead of 40 ms for 64 files beside 400 MB of other
        writes), and an fsync of each directory doubled the journal commits (the rename
        is in the journal transaction that the database's commit fsync flushes)."""
        results: list[tuple[str, bool]] = []
        pending: dict[str, tuple[bytes, Path, Path]] = {}  # sha256 -> (data, temporary, path)
        for data, sha in files:
            path = self.path(sha)
            new = sha not in pending and not path.is_file()
            if new:
                tmp = path.with_name(f".{sha}.{os.getpid()}.{threading.get_ident()}.tmp")
                pending[sha] = (data, tmp, path)
            results.append((sha, new))
        if not pending:
            return results
        opened: list[int] = []
        renamed: list[Path] = []
        try:
            for data, tmp, path in pending.values():
                path.parent.mkdir(parents=True, exist_ok=True)
                opened.append(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644))
                _write_all(opened[-1], data)
            _each(os.fsync, opened)  # the bytes on disk before a name points at them
            while opened:
                os.close(opened.pop())
            for _, tmp, path in pending.values():
                os.replace(tmp, path)  # readers never see a half-written file
                renamed.append(path)
        except OSError as exc:
            for fd in opened:
                with contextlib.suppress(OSError):
                    os.close(fd)
            for _, tmp, _ in pending.values():
                with contextlib.suppress(OSError):
                    tmp.unlink(missing_ok=True)
            for path in renamed:
                with contextlib.suppress(OSError):
                    path.unlink(missing_ok=True)
            raise StorageUnavailable(f"cannot store the uploaded file: {exc.strerror}") from exc
        return results

    def read(self, sha256: str) -> bytes:
        try:
            return self.path(sha256).read_bytes()
        except OSError as exc:
            raise StorageUnavailable(
                f"stored file {sha256[:12]}... cannot be read: {exc.strerror}"
            ) from exc

    def exists(self, sha256: str) -> bool:
        return self.path(sha256).is_file()

    def delete(self, sha256: str) -> None:
        path = self.path(sha256)
        path.unlink(missing_ok=True)
        with contextlib.suppress(OSError):  # removes the fan-out directory only when empty
            path.parent.rmdir()

    def claim(self, session: Session, files: Sequence[tuple[bytes, str]]) -> list[str]:
        # ``session`` holds SQLite's write lock, as every release does: nothing is removed
        # between this look and the commit.
        return [sha for sha, new in self.put_many(files) if new]

    def release(self, session: Session, shas: Iterable[str]) -> int:
        wanted = set(shas)
        unused = wanted - clip_db.referenced_blobs(session, wanted)
        for sha in sorted(unused):  # under the write lock: no claim runs meanwhile
            self.delete(sha)
        return len(unused)

    def stored(self) -> Iterator[tuple[str, Path]]:
        """Every stored file as ``(sha256, path)``; temporary and foreign files are skipped."""
        if not self.root.is_dir():
            return
        for fan_out in sorted(self.root.iterdir()):
            if not fan_out.is_dir() or len(fan_out.name) != 2:
                continue
            for path in sorted(fan_out.iterdir()):
                if _SHA256.fullmatch(path.name) and path.name[:2] == fan_out.name:
                    yield path.name, path

    def temporary_files(self) -> Iterator[Path]:
        """Half-written files a crash left behind (``<fan-out>/.<sha256>.<pid>.<thread>.tmp``)."""
        if self.root.is_dir():
            yield from self.root.glob("??/.*.tmp")

    def sweep(
        self, listed: list[tuple[str, Path]], referenced: set[str], *, older_than: float
    ) -> int:
        """Delete the ``listed`` files (from :meth:`stored`) not in ``referenced``, and the
        temporary files, both only when last modified before ``older_than`` (a ``time.time()``
        value); returns how many went."""
        removed = 0
        candidates = [path for sha, path in listed if sha not in referenced]
        for path in [*candidates, *self.temporary_files()]:
            try:
                if path.stat().st_mtime >= older_than:
                    continue
                path.unlink()
            except FileNotFoundError:
                continue
            removed += 1
            with contextlib.suppress(OSError):
                path.parent.rmdir()
        return removed

    def remove_unreferenced(self, session: Session, *, older_than: float) -> int:
        listed = list(self.stored())
        shas = [sha for sha, _ in listed]
        referenced: set[str] = set()
        for start in range(0, len(shas), IN_CHUNK):
            referenced |= clip_db.referenced_blobs(session, shas[start : start + IN_CHUNK])
        return self.sweep(listed, referenced, older_than=older_than)


class DatabaseBlobStore:
    """Rows of the ``blobs`` table (PostgreSQL deployments: any number of machines). Each
    ``put`` commits on its own, before the clip that names the file, as a file is written
    before its clip on SQLite."""

    def __init__(self, engine: Engine) -> None:
        self._engine = engine

    def put(self, data: bytes) -> tuple[str, bool]:
        # PostgreSQL's dialect is imported here, not with the module: a SQLite server's
        # workers would load it at every start for nothing (~0.1 s of CPU each).
        from sqlalchemy.dialects.postgresql import insert as pg_insert

        sha = hashlib.sha256(data).hexdigest()
        statement = (
            pg_insert(Blob)
            .values(sha256=sha, size=len(data), data=data, created_at=datetime.now(UTC))
            .on_conflict_do_nothing(index_elements=[Blob.sha256])
            .returning(Blob.sha256)
        )
        try:
            with self._engine.begin() as connection:
                new = connection.execute(statement).first() is not None
        except SQLAlchemyError as exc:
            raise StorageUnavailable(f"cannot store the uploaded file: {exc}") from exc
        return sha, new

    def put_many(self, files: Sequence[tuple[bytes, str]]) -> list[tuple[str, bool]]:
        results: list[tuple[str, bool]] = []
        try:
            for data, _ in files:
                results.append(self.put(data))
        except BaseException:
            for sha, new in results:
                if new:
                    self.delete(sha)
            raise
        return results

    def read(self, sha256: str) -> bytes:
        try:
            with self._engine.connect() as connection:
                data = connection.scalar(
                    select(Blob.data).where(Blob.sha256 == _check_sha256(sha256))
                )
        except SQLAlchemyError as exc:
            raise StorageUnavailable(f"stored file {sha256[:12]}... cannot be read: {exc}") from exc
        if data is None:
            raise StorageUnavailable(f"stored file {sha256[:12]}... is missing from the database")
        return bytes(data)

    def exists(self, sha256: str) -> bool:
        with self._engine.connect() as connection:
            found = connection.scalar(select(Blob.sha256).where(Blob.sha256 == sha256))
        return found is not None

    def delete(self, sha256: str) -> None:
        # Only while unreferenced: a clip committed meanwhile by another replica keeps it.
        with Session(self._engine) as session, session.begin():
            self.release(session, [sha256])

    def claim(self, session: Session, files: Sequence[tuple[bytes, str]]) -> list[str]:
        from sqlalchemy.dialects.postgresql import insert as pg_insert  # see put

        wanted = {sha: data for data, sha in files}
        # FOR SHARE: a removal (FOR UPDATE) waits for this transaction; in sha256 order, as
        # removals lock, so two transactions never wait for each other.
        held = set(
            session.scalars(
                select(Blob.sha256)
                .where(Blob.sha256.in_(sorted(wanted)))
                .order_by(Blob.sha256)
                .with_for_update(read=True)
            )
        )
        missing = sorted(set(wanted) - held)
        for sha in missing:  # removed since it was put: store it again, locked (DO UPDATE)
            data = wanted[sha]
            statement = pg_insert(Blob).values(
                sha256=sha, size=len(data), data=data, created_at=datetime.now(UTC)
            )
            session.execute(
                statement.on_conflict_do_update(
                    index_elements=[Blob.sha256], set_={"size": statement.excluded.size}
                )
            )
        return missing

    def release(self, session: Session, shas: Iterable[str]) -> int:
        wanted = sorted(set(shas))
        if not wanted:
            return 0
        return self._remove_locked(
            session, select(Blob.sha256).where(Blob.sha256.in_(wanted)).with_for_update()
        )

    def remove_unreferenced(self, session: Session, *, older_than: float) -> int:
        cutoff = datetime.fromtimestamp(older_than, UTC)
        candidates = select(Blob.sha256).where(Blob.created_at < cutoff, ~_referenced(Blob.sha256))
        # Files a claim holds are skipped, not waited for: they are in use.
        return self._remove_locked(session, candidates.with_for_update(skip_locked=True))

    @staticmethod
    def _remove_locked(session: Session, rows: Select[Any]) -> int:
        """Lock the blob rows ``rows`` selects (sha256 order, as claims lock), then delete
        those no clip refers to: in a statement of its own, whose snapshot (READ COMMITTED)
        sees every clip committed before the locks were granted."""
        locked = list(session.scalars(rows.order_by(Blob.sha256)))
        removed = 0
        for start in range(0, len(locked), IN_CHUNK):
            chunk = locked[start : start + IN_CHUNK]
            result = session.execute(
                delete(Blob).where(Blob.sha256.in_(chunk), ~_referenced(Blob.sha256))
            )
            removed += int(result.rowcount or 0)  # type: ignore[attr-defined]
        return removed


SYNC_THREADS = 8  # fsyncs in flight at once (they wait on the disk, not the CPU)
_sync_pool: ThreadPoolExecutor | None = None
_sync_pool_lock = threading.Lock()


def _each(action: Callable[[Any], None], items: Sequence[Any]) -> None:
    """``action(item)`` for every item, a few at a time on a shared pool of threads (one
    alone in this thread); raises the first error once all are done."""
    global _sync_pool
    if len(items) <= 1:
        for item in items:
            action(item)
        return
    with _sync_pool_lock:
        if _sync_pool is None:
            _sync_pool = ThreadPoolExecutor(SYNC_THREADS, thread_name_prefix="mocap-fsync")
        pool = _sync_pool
    futures = [pool.submit(action, item) for item in items]
    errors = [future.exception() for future in futures]
    for error in errors:
        if error is not None:
            raise error


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _referenced(sha256: Any) -> Exists:
    return exists().where(ClipFile.sha256 == sha256)


def open_blob_store(engine: Engine, files_dir: Path) -> BlobStore:
    """The database itself on PostgreSQL, the ``files_dir`` directory otherwise."""
    if engine.dialect.name == "postgresql":
        return DatabaseBlobStore(engine)
    return FileBlobStore(files_dir)
