"""The import run: find the clips, feed the workers, store what they describe in batches
(see :mod:`app.importer`)."""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from multiprocessing.connection import wait
from pathlib import Path
from typing import TYPE_CHECKING

from app.discovery import ClipSource, discover
from app.errors import MocapError
from app.importer.label_rules import LabelRules
from app.importer.refusals import REFUSALS_FILE, RefusalMemory
from app.importer.report import Duplicate, Failed, Imported, ImportReport
from app.importer.workers import TASKS_PER_WORKER, Outcome, TaskClip, WorkerPool, read_upload
from app.services.describe import Description
from app.services.uploads import Upload

if TYPE_CHECKING:
    from app.config import Settings
    from app.services.ingest import Described, IngestResult
    from app.services.library import Library

DEFAULT_BATCH_SIZE = 64
MAX_TASK_CLIPS = 8
FLUSH_AFTER_SECONDS = 1.0  # store a partial batch once its oldest clip waited this long
POLL_SECONDS = 0.2


@dataclass
class _Item:
    number: int
    source: ClipSource
    labels: list[str]
    notes: dict[str, str] = field(default_factory=dict)  # source, licence
    upload: Upload | None = None  # read by the main process (for hashing and storing)
    shas: tuple[str, ...] | None = None  # sha256 of each file as the worker read it
    retried: bool = False


def default_workers(settings: Settings) -> int:
    return settings.import_workers or os.cpu_count() or 1


@contextmanager
def _graceful_sigterm() -> Iterator[None]:
    """SIGTERM stops the run like Ctrl-C does (what is committed stays, the rest is not)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


Progress = Callable[[ImportReport], None]


def run_import(
    settings: Settings,
    paths: Sequence[Path],
    *,
    labels: LabelRules | None = None,
    workers: int | None = None,
    batch_size: int = DEFAULT_BATCH_SIZE,
    progress: Progress | None = None,
    on_start: Callable[[int, int], None] | None = None,
) -> ImportReport:
    """Import every clip under ``paths``; see the module docstring.

    ``progress(report)`` is called as clips finish; ``on_start(found, workers)`` once the
    clips are found. Ctrl-C (or SIGTERM) ends the run early with ``report.interrupted``.
    """
    started = time.perf_counter()
    rules = labels or LabelRules()
    found = discover([Path(p) for p in paths], scenes=True)
    report = ImportReport(found=len(found.sources) + len(found.failures))
    report.failed.extend(Failed(f.path, f.reason, refused=True) for f in found.failures)
    items = deque(
        _Item(number, source, rules.labels(source), rules.notes_of(source))
        for number, source in enumerate(found.sources)
    )
    size = max(1, min(workers or default_workers(settings), len(items)))
    report.workers = size if items else 0
    if on_start is not None:
        on_start(report.found, report.workers)
    memory = RefusalMemory(settings.data_dir / REFUSALS_FILE)
    found_paths = {source.motion for source in found.sources}
    if not items:
        memory.settle(report, found_paths)
        report.seconds = time.perf_counter() - started
        return report

    pool = WorkerPool(
        size,
        settings.parse_limits,
        settings.max_frame_values,
        (settings.parser_timeout_seconds, settings.parser_memory_mb),
        windows=settings.moments,
    )
    opener = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mocap-import-open")
    library_future: Future[Library] = opener.submit(_open_library, settings)
    run = _Run(report, pool, library_future, opener, items, batch_size, progress)
    try:
        with _graceful_sigterm():
            run.loop()
    except KeyboardInterrupt:
        report.interrupted = True
    finally:
        pool.close()
        with suppress(KeyboardInterrupt):
            run.finish_store(wait_for_it=True)  # a batch being stored is committed: say so
        opener.shutdown(wait=True)
        run.close()
        if library_future.done() and library_future.exception() is None:
            library = library_future.result()
            try:
                library.close()  # saves the indexes that changed
            except Exception as error:
                print(f"mocap-index: could not save the indexes: {error}", file=sys.stderr)
    memory.settle(report, found_paths)
    report.seconds = time.perf_counter() - started
    return report


def _open_library(settings: Settings) -> Library:
    from app.services.library import open_library

    library = open_library(settings)
    # Saved once, when the run ends (Library.close): small indexes would otherwise be
    # written (and hashed, and fsynced) every second of the run, the window indexes too.
    for index in [*library.indexes.values(), *library.window_indexes.values()]:
        index.autosave = False
    library.catalogue.autosave = False
    return library


class _Run:
    """The main process's loop: feed the workers, collect outcomes, store batches."""

    def __init__(
        self,
        report: ImportReport,
        pool: WorkerPool,
        library: Future[Library],
        library_thread: ThreadPoolExecutor,
        items: deque[_Item],
        batch_size: int,
        progress: Progress | None,
    ) -> None:
        self.report = report
        self.pool = pool
        self.library_future = library
        self.pending = items
        self.by_number = {item.number: item for item in items}
        self.batch_size = max(1, batch_size)
        self.progress = progress or (lambda _report: None)
        self.ready: list[tuple[_Item, Description | None]] = []
        self.ready_since = 0.0
        # Batches are stored on the thread that opened the library, one at a time; its
        # pipe wakes this loop when one is done.
        self.storer = library_thread
        self.storing: tuple[list[tuple[_Item, Described]], Future[list[IngestResult]]] | None = None
        self.stored_signal, self._stored_writer = multiprocessing.Pipe(duplex=False)
        workers = len(pool.workers)
        self.task_clips = max(1, min(MAX_TASK_CLIPS, len(items) // (workers * 8) or 1))

    def close(self) -> None:
        self.stored_signal.close()
        self._stored_writer.close()

    # -- helpers ------------------------------------------------------------------------

    @property
    def library(self) -> Library | None:
        if not self.library_future.done():
            return None
        return self.library_future.result()  # raises when opening failed

    def fail(self, item: _Item, reason: str, *, refused: bool = False) -> None:
        self.report.failed.append(Failed(item.source.motion, reason, refused))
        self.by_number.pop(item.number, None)

    def upload_of(self, item: _Item) -> Upload | None:
        if item.upload is None:
            try:
                item.upload = read_upload(item.source, item.labels, item.notes)
            except MocapError as error:
                self.fail(item, error.detail, refused=True)
            except OSError as error:
                self.fail(item, f"cannot read the file: {error.strerror or error}")
        return item.upload

    def next_task(self, library: Library | None) -> list[TaskClip]:
        """Up to ``task_clips`` clips to describe; once the library is open, content already
        stored goes straight to the store queue (it is not described again)."""
        chosen: list[_Item] = []
        while self.pending and len(chosen) < self.task_clips:
            chosen.append(self.pending.popleft())
        if library is not None and chosen:
            from app.db import clips as clip_db

            readable = [item for item in chosen if self.upload_of(item) is not None]
            # An FBX/glTF file's clips are known once it is read: always described.
            hashes = [
                item.upload.content_hash
                for item in readable
                if item.upload and item.upload.knows_content_hash
            ]
            with library.reads() as session:
                stored = clip_db.clip_ids_by_hash(session, hashes)
            chosen = []
            for item in readable:
                assert item.upload is not None
                if item.upload.knows_content_hash and item.upload.content_hash in stored:
                    self.queue(item, None)
                else:
                    chosen.append(item)
        return [
            (item.number, item.source.kind, tuple(str(p) for p in item.source.paths))
            for item in chosen
        ]

    def queue(self, item: _Item, description: Description | None) -> None:
        if not self.ready:
            self.ready_since = time.monotonic()
        self.ready.append((item, description))

    # -- the loop -----------------------------------------------------------------------

    def loop(self) -> None:
        while self.pending or self.pool.busy() or self.ready or self.storing is not None:
            library = self.library
            gone = False
            for worker in self.pool.free_slots():
                while len(worker.tasks) < TASKS_PER_WORKER and self.pending:
                    task = self.next_task(library)
                    if task and not self.pool.submit(worker, task):
                        # Gone since the last collect (which replaces it): the clips wait.
                        self.pending.extendleft(self.by_number[n] for n, _, _ in reversed(task))
                        gone = True
                        break
            if self.pool.busy() or gone:
                outcomes, lost = self.pool.collect(
                    POLL_SECONDS if library else 0.05, also=[self.stored_signal]
                )
                for number, outcome in outcomes:
                    self.receive(number, outcome)
                for task in lost:
                    self.requeue(task)
            elif self.storing is not None:
                wait([self.stored_signal], POLL_SECONDS)
            elif self.ready and library is None:
                self.library_future.exception()  # nothing else to do: wait for the library
            self.finish_store()
            library = self.library
            if library is not None and self.ready and self.storing is None:
                idle = not self.pending and not self.pool.busy()
                waited = time.monotonic() - self.ready_since >= FLUSH_AFTER_SECONDS
                if idle or waited or len(self.ready) >= self.batch_size:
                    self.start_store(library)

    def receive(self, number: int, outcome: Outcome) -> None:
        item = self.by_number.get(number)
        if item is None:
            return
        status, value, shas = outcome
        if status != "ok":
            self.fail(item, str(value), refused=status == "refused")
            self.progress(self.report)
            return
        item.shas = shas
        for description in value:
            self.queue(item, description)

    def requeue(self, task: list[TaskClip]) -> None:
        """The worker describing ``task`` died: retry its clips one at a time; a clip that
        was already alone in its task is the culprit."""
        for number, _, _ in task:
            item = self.by_number.get(number)
            if item is None:
                continue
            if item.retried or len(task) == 1:
                self.fail(item, "the worker process describing it died (crash or out of memory)")
                self.progress(self.report)
            else:
                item.retried = True
                self.pending.appendleft(item)
        if len(task) > 1:
            self.task_clips = 1  # isolate the culprit

    def start_store(self, library: Library) -> None:
        """Store the ready clips on the library's thread. Meanwhile this loop keeps feeding
        the workers and reading their outcomes: a worker whose outcomes fill its pipe waits
        until they are read, so storing here would leave the cores idle."""
        from app.services.ingest import Described, described_upload, store_many

        batch, self.ready = self.ready, []
        described: list[tuple[_Item, Described]] = []
        failed: set[int] = set()
        for item, description in sorted(batch, key=lambda pair: pair[0].number):
            upload = self.upload_of(item)
            if upload is None or item.number in failed:
                continue
            if item.shas is not None and item.shas != tuple(p.sha256 for p in upload.parts):
                self.fail(item, "the file changed while it was being imported")
                failed.add(item.number)
                continue
            if description is not None:
                upload = described_upload(upload, description)
            described.append((item, Described(upload, description)))
        future = self.storer.submit(store_many, library, [d for _, d in described])
        future.add_done_callback(lambda _: self._stored_writer.send_bytes(b"."))
        self.storing = (described, future)

    def finish_store(self, wait_for_it: bool = False) -> None:
        """Report the batch being stored once it is (``wait_for_it``: wait for that)."""
        if self.storing is None:
            return
        described, future = self.storing
        if not (wait_for_it or future.done()):
            return
        self.storing = None
        while self.stored_signal.poll():
            self.stored_signal.recv_bytes()
        try:
            results = future.result()
        except MocapError as error:
            for item, _ in described:
                self.fail(item, f"not stored: {error.detail}")
        else:
            for (item, _), result in zip(described, results, strict=True):
                self.by_number.pop(item.number, None)
                if result.created:
                    self.report.imported.append(
                        Imported(item.source.motion, result.clip.id, item.source.skeleton)
                    )
                else:
                    self.report.duplicates.append(
                        Duplicate(
                            item.source.motion, result.clip.id, result.clip.name, result.changed
                        )
                    )
        self.progress(self.report)
