"""``mocap-index import PATH...``: a folder of clips into the library, in parallel processes.

Pipeline
    :func:`app.discovery.discover` finds the clips (``.bvh`` files, ``.amc`` files paired with
    an ``.asf`` of their folder — an ``.amc`` without one is a failure —, and ``.fbx``,
    ``.glb``, ``.gltf``, ``.vrma`` files, whose every animation of at least
    :data:`MIN_ANIMATION_FRAMES` frames becomes a clip named ``<file> · <animation>``; a file
    with none that long gives its longest). Worker processes (one
    per core by default) read, parse and describe the clips, a few per task, and send back
    only the measurements, vectors and stored previews (the figure a page draws, made from
    the body the describer built: ~8 KB a second of motion). The main process meanwhile
    opens the library (imports, migration, indexes) in a thread, then stores the described
    clips in batches through :func:`app.services.ingest.store_many` — the code ``POST
    /clips`` uses: files, then one transaction per batch, then one index update per batch,
    then the batch's previews. Batches are stored one at a time on that same thread while the
    main loop goes on feeding the workers and reading their outcomes (a worker waits once its
    outcomes fill the pipe; bench/README.md has the figures).

Idempotent and resumable
    A clip is identified by its content hash (:func:`app.discovery.content_hash`, the rule
    uploads use). Once the library is open, content already stored is recognised before it is
    described and reported as a duplicate; ``store_many`` settles the rest (and races with
    other writers). Every batch commits atomically, so a run stopped half way (Ctrl-C,
    SIGTERM, SIGKILL) loses at most the batch in flight, and running it again stores what is
    missing and nothing twice. Index files are saved when the run ends; a run that was killed
    leaves them behind the database, and whoever opens the library next adds the missing
    vectors from the database.

Workers
    Workers import only the motion core (numpy, scipy), never SQLAlchemy or FAISS. They are
    forked from the main process before it starts any thread (cheapest start), else started
    from a fork server. A worker that dies (a crash in native code, the out-of-memory killer)
    costs one clip: the clips of its task are retried one by one in a new worker, and the one
    that kills a worker again is reported as failed. Workers exit when the main process goes
    away. FBX/glTF readers run in the workers themselves under MOCAP_PARSER_TIMEOUT_SECONDS
    and MOCAP_PARSER_MEMORY_MB (:class:`~app.services.parser_pool.InlineParser`): a reader
    that crashes or overruns costs its worker, like any crash here.

This module imports neither SQLAlchemy nor FAISS at module level (workers import it too).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import multiprocessing
import os
import re
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.discovery import ClipSource, discover
from app.errors import InvalidInput, MocapError
from app.labels import (
    choose_label_columns,
    compile_label_regex,
    labels_from_regex,
    labels_from_tsv,
    normalise_labels,
)
from app.motion.model import ParseLimits
from app.services.describe import Description, MotionDescriber
from app.services.parser_pool import InlineParser
from app.services.uploads import Upload, normalise_note

if TYPE_CHECKING:
    from app.config import Settings
    from app.services.ingest import Described, IngestResult
    from app.services.library import Library

DEFAULT_BATCH_SIZE = 64
MIN_ANIMATION_FRAMES = 5  # shorter animations of a multi-animation file are not imported
MAX_TASK_CLIPS = 8
TASKS_PER_WORKER = 2  # in flight: one being described, one waiting
FLUSH_AFTER_SECONDS = 1.0  # store a partial batch once its oldest clip waited this long
POLL_SECONDS = 0.2
WORKER_NICENESS = 5


# ------------------------------------------------------------------------------ reports


@dataclass(frozen=True)
class Imported:
    path: Path
    clip_id: int
    skeleton: Path | None  # the .asf an .amc was paired with


@dataclass(frozen=True)
class Duplicate:
    path: Path
    clip_id: int
    clip_name: str
    updated: bool = False  # the import gave the stored clip new labels (or source, licence)


@dataclass(frozen=True)
class Failed:
    """A clip not stored: ``refused`` when its file cannot be stored as it is (a parse error,
    no skeleton, an ``.amc`` without ``.asf``: running again changes nothing), not when the
    run failed it (storage, a crash, a file unreadable or changing meanwhile)."""

    path: Path
    reason: str
    refused: bool = False


@dataclass
class ImportReport:
    """What a run did: every clip found ends in exactly one of the three lists."""

    found: int = 0
    imported: list[Imported] = field(default_factory=list)
    duplicates: list[Duplicate] = field(default_factory=list)
    failed: list[Failed] = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0
    workers: int = 0
    # Refusals an earlier run reported for the same bytes with the same reason (see
    # RefusalMemory): expected, so they do not fail the run unless --strict.
    known_refusals: set[Path] = field(default_factory=set)

    @property
    def new_failures(self) -> list[Failed]:
        """The failures no earlier run reported: every failure but known refusals."""
        return [f for f in self.failed if not (f.refused and f.path in self.known_refusals)]

    @property
    def done(self) -> int:
        return len(self.imported) + len(self.duplicates) + len(self.failed)

    def skeletons(self) -> dict[Path, int]:
        """The ``.asf`` files ASF/AMC clips were imported with, and how many clips each."""
        used: dict[Path, int] = {}
        for clip in self.imported:
            if clip.skeleton is not None:
                used[clip.skeleton] = used.get(clip.skeleton, 0) + 1
        return used


# ------------------------------------------------------------------------------- labels

# TSV columns that say where a clip comes from and how it may be used: not labels.
NOTE_COLUMNS = {"source": "source", "licence": "licence", "license": "licence"}


@dataclass(frozen=True)
class LabelRules:
    """Where the labels of an imported clip come from.

    ``tsv``: clip key (file stem) -> {kind: value}; ``regex``: named groups over the path
    relative to the folder given (``kind`` = group name); ``fixed``: labels every clip gets.
    A clip is stored with the values (kinds are not stored), TSV first, then the regex's
    groups, then ``fixed``; repeated values are kept once.

    The TSV columns named ``source`` and ``licence`` (or ``license``) are not labels: they
    give the clip's source and licence (``notes``). Of the other columns, ``columns`` chooses
    the label columns; by default those not holding free text
    (:func:`app.labels.choose_label_columns`); ``left_out`` names the others.
    """

    tsv: dict[str, dict[str, str]] | None = None
    regex: re.Pattern[str] | None = None
    fixed: tuple[str, ...] = ()
    notes: dict[str, dict[str, str]] = field(default_factory=dict)
    left_out: tuple[str, ...] = ()
    fixed_notes: dict[str, str] = field(default_factory=dict)  # --source, --licence

    @classmethod
    def build(
        cls,
        *,
        tsv: Path | None = None,
        regex: str | None = None,
        fixed: Sequence[str] = (),
        columns: Sequence[str] | None = None,
        source: str | None = None,
        licence: str | None = None,
    ) -> LabelRules:
        """Read the TSV and compile the regex (:class:`InvalidInput` when unusable);
        ``source`` and ``licence`` are every clip's unless its TSV row gives its own."""
        table: dict[str, dict[str, str]] | None = None
        notes: dict[str, dict[str, str]] = {}
        left_out: tuple[str, ...] = ()
        if tsv is not None:
            rows = labels_from_tsv(tsv)
            notes = {
                key: {NOTE_COLUMNS[k]: v for k, v in row.items() if k in NOTE_COLUMNS}
                for key, row in rows.items()
            }
            tags = {
                k: {c: v for c, v in r.items() if c not in NOTE_COLUMNS} for k, r in rows.items()
            }
            table, left_out = choose_label_columns(tags, columns)
        elif columns is not None:
            raise InvalidInput("--label-columns chooses columns of --labels-tsv; give that too")
        return cls(
            tsv=table,
            regex=compile_label_regex(regex) if regex is not None else None,
            fixed=normalise_labels(fixed),
            notes=notes,
            left_out=left_out,
            fixed_notes={
                key: note
                for key, value in (("source", source), ("licence", licence))
                if (note := normalise_note(f"--{key}", value)) is not None
            },
        )

    def notes_of(self, source: ClipSource) -> dict[str, str]:
        """The clip's source and licence: its TSV row's, else the command line's."""
        return {**self.fixed_notes, **self.notes.get(source.name, {})}

    def labels(self, source: ClipSource) -> list[str]:
        kinds: dict[str, str] = {}
        if self.tsv is not None:
            kinds.update(self.tsv.get(source.name, {}))
        if self.regex is not None:
            kinds.update(labels_from_regex(self.regex, source.relative_path))
        return [*kinds.values(), *self.fixed]


# ------------------------------------------------------------------------------ workers

TaskClip = tuple[int, str, tuple[str, ...]]  # (item number, kind, paths: bvh | asf, amc)
# ("ok", [Description, ...], part sha256s) | ("refused" or "error", reason, None): refused,
# the file cannot be stored as it is; error, describing it failed. FBX/glTF files give a
# description per animation imported (each knows its animation), others one.
Outcome = tuple[str, Any, Any]


def read_upload(
    source: ClipSource, labels: Sequence[str] = (), notes: Mapping[str, str] | None = None
) -> Upload:
    """The clip's files as an :class:`Upload` (what ``POST /clips`` would receive);
    ``notes`` may give its ``source`` and ``licence``."""
    notes = notes or {}
    motion = (source.motion.name, source.motion.read_bytes())
    skeleton = (
        None if source.skeleton is None else (source.skeleton.name, source.skeleton.read_bytes())
    )
    return Upload.from_files(
        file=motion if skeleton is None else None,
        skeleton=skeleton,
        motion=None if skeleton is None else motion,
        labels=labels,
        source=notes.get("source"),
        licence=notes.get("licence"),
    )


def _source_of(kind: str, paths: tuple[str, ...]) -> ClipSource:
    if kind != "asf/amc":
        motion = Path(paths[0])
        return ClipSource(kind, motion, None, motion.stem, motion.name, motion.parent)  # type: ignore[arg-type]
    skeleton, motion = Path(paths[0]), Path(paths[1])
    return ClipSource("asf/amc", motion, skeleton, motion.stem, motion.name, motion.parent)


def describe_animations(
    describer: MotionDescriber, upload: Upload, limits: ParseLimits
) -> list[Description]:
    """Every clip of an upload: one, or for an FBX/glTF file one per animation of at least
    :data:`MIN_ANIMATION_FRAMES` frames (the longest when none is that long)."""
    first = describer.describe(upload, limits)
    if first.animation is None:
        return [first]
    described = {first.animation: first}
    for animation in first.animations:
        if animation.frame_count < MIN_ANIMATION_FRAMES or animation.name in described:
            continue
        chosen = dataclasses.replace(upload, animation=animation.name)
        described[animation.name] = describer.describe(chosen, limits)
    return list(described.values())


def _describe_one(describer: MotionDescriber, limits: ParseLimits, clip: TaskClip) -> Outcome:
    _, kind, paths = clip
    try:
        upload = read_upload(_source_of(kind, paths))
        descriptions = describe_animations(describer, upload, limits)
        return ("ok", descriptions, tuple(part.sha256 for part in upload.parts))
    except MocapError as error:
        return ("refused", error.detail, None)
    except OSError as error:
        return ("error", f"cannot read the file: {error.strerror or error}", None)
    except MemoryError:
        return ("error", "out of memory while describing it", None)
    except Exception as error:  # any failure of one clip must not stop the run
        return ("error", f"{type(error).__name__}: {error}", None)


def _worker_main(
    conn: Connection,
    parent: int,
    limits: ParseLimits,
    max_values: int | None,
    parser_limits: tuple[float | None, int | None] = (None, None),
    windows: bool = True,
) -> None:
    """A worker's loop: describe the clips of each task until told to stop or orphaned."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the main process to handle
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    # One thread in polars' frame reader (app.motion.formats.bvh): the workers are the
    # parallelism; its own threads cost CPU here (2.9 -> 2.4 ms per Bandai clip).
    os.environ.setdefault("POLARS_MAX_THREADS", "1")
    with suppress(OSError):
        # Below the main process, whose work (opening the library, storing) is what the
        # workers wait for; and kinder to whatever else the machine runs.
        os.nice(WORKER_NICENESS)
    time_limit, memory_mb = parser_limits
    parsers = InlineParser(time_limit=time_limit, memory_mb=memory_mb)
    describer = MotionDescriber(max_values=max_values, parsers=parsers, windows=windows)
    while True:
        try:
            if not conn.poll(1.0):
                if os.getppid() != parent:  # the main process is gone (killed)
                    return
                continue
            task = conn.recv()
        except (EOFError, OSError):
            return
        if task is None:
            return
        task_id, clips = task
        outcomes = [(clip[0], _describe_one(describer, limits, clip)) for clip in clips]
        try:
            conn.send((task_id, outcomes))
        except (BrokenPipeError, OSError):
            return


def _context() -> Any:
    """Fork while this process has no other thread (fastest: the motion core is already
    imported); a fork server otherwise (forking a process with threads is unsafe). polars,
    once imported (a BVH was read here before), has native threads of its own."""
    methods = multiprocessing.get_all_start_methods()
    if "fork" in methods and threading.active_count() == 1 and "polars" not in sys.modules:
        return multiprocessing.get_context("fork")
    if "forkserver" in methods:
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(["app.importer"])
        return context
    return multiprocessing.get_context("spawn")


@dataclass
class _Worker:
    process: Any
    conn: Connection
    tasks: dict[int, list[TaskClip]] = field(default_factory=dict)


class WorkerPool:
    """``size`` worker processes, each fed up to :data:`TASKS_PER_WORKER` tasks at a time."""

    def __init__(
        self,
        size: int,
        limits: ParseLimits,
        max_values: int | None,
        parser_limits: tuple[float | None, int | None] = (None, None),
        windows: bool = True,
    ) -> None:
        self._limits = limits
        self._max_values = max_values
        self._parser_limits = parser_limits
        self._windows = windows
        self._context = _context()
        self.workers: list[_Worker] = []
        for _ in range(size):
            self._start()
        self._next_task = 0

    def _start(self, context: Any = None) -> None:
        context = context or self._context
        ours, theirs = context.Pipe()
        process = context.Process(
            target=_worker_main,
            args=(
                theirs,
                os.getpid(),
                self._limits,
                self._max_values,
                self._parser_limits,
                self._windows,
            ),
            name="mocap-import-worker",
            daemon=True,
        )
        process.start()
        theirs.close()
        self.workers.append(_Worker(process, ours))

    def free_slots(self) -> list[_Worker]:
        return [w for w in self.workers if len(w.tasks) < TASKS_PER_WORKER]

    def busy(self) -> bool:
        return any(w.tasks for w in self.workers)

    def submit(self, worker: _Worker, clips: list[TaskClip]) -> None:
        self._next_task += 1
        worker.tasks[self._next_task] = clips
        worker.conn.send((self._next_task, clips))

    def collect(
        self, timeout: float, also: Sequence[Connection] = ()
    ) -> tuple[list[tuple[int, Outcome]], list[list[TaskClip]]]:
        """Outcomes that arrived within ``timeout`` (or until one of ``also`` is readable),
        and the tasks of workers that died (those workers are replaced)."""
        ready = wait(
            [w.conn for w in self.workers] + [w.process.sentinel for w in self.workers] + [*also],
            timeout,
        )
        outcomes: list[tuple[int, Outcome]] = []
        lost: list[list[TaskClip]] = []
        for worker in list(self.workers):
            alive = worker.process.is_alive()
            if worker.conn in ready or not alive:
                try:
                    while worker.conn.poll():
                        task_id, results = worker.conn.recv()
                        worker.tasks.pop(task_id, None)
                        outcomes.extend(results)
                except (EOFError, OSError):
                    alive = False
            if alive:
                continue
            worker.process.join(timeout=1)
            if worker.process.is_alive():  # its pipe broke but it still runs: stop it
                worker.process.kill()
                worker.process.join()
            lost.extend(worker.tasks.values())
            worker.conn.close()
            self.workers.remove(worker)
            # A replacement; from a fork server, since this process has threads by now.
            self._start(multiprocessing.get_context("forkserver"))
        return outcomes, lost

    def close(self) -> None:
        for worker in self.workers:
            with suppress(OSError):
                worker.conn.send(None)
        deadline = time.monotonic() + 2
        for worker in self.workers:
            worker.process.join(timeout=max(0.0, deadline - time.monotonic()))
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join()
            worker.conn.close()
        self.workers = []


# ------------------------------------------------------------------------------- import


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


# ---------------------------------------------------------------- refusals remembered

REFUSALS_FILE = "import-refusals.json"


def _file_sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


class RefusalMemory:
    """The files earlier runs refused, so a run over the same folders can tell a new failure
    from one already reported: ``<data dir>/import-refusals.json`` maps each refused file's
    absolute path to the sha256 of its bytes and the reason given. A refusal is *known* when
    the same bytes were refused for the same reason before; editing the file, or a release
    that refuses it for another reason, makes it new again."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def _load(self) -> dict[str, dict[str, str]]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            refused = data["refused"]
        except (OSError, ValueError, KeyError, TypeError):
            return {}  # none yet (or unreadable: every refusal counts as new, once)
        return {
            str(path): entry
            for path, entry in refused.items()
            if isinstance(entry, dict) and {"sha256", "reason"} <= entry.keys()
        }

    def settle(self, report: ImportReport, found: set[Path]) -> None:
        """Mark the report's known refusals, then remember this run's: its refusals replace
        what was remembered of their files, and files it found and did not refuse are
        forgotten (files under other folders are kept)."""
        remembered = self._load()
        seen = {str(path.resolve()) for path in found}
        refusals: dict[str, dict[str, str]] = {}
        for failure in report.failed:
            if not failure.refused:
                continue
            key = str(failure.path.resolve())
            seen.add(key)
            sha = _file_sha256(failure.path)
            if sha is None:
                continue
            entry = {"sha256": sha, "reason": failure.reason}
            if remembered.get(key) == entry:
                report.known_refusals.add(failure.path)
            refusals[key] = entry
        kept = {key: entry for key, entry in remembered.items() if key not in seen}
        if not refusals and kept == remembered:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            partial = self.path.with_name(self.path.name + ".partial")
            text = json.dumps({"refused": {**kept, **refusals}}, indent=1, sort_keys=True)
            partial.write_text(text, encoding="utf-8")
            partial.replace(self.path)
        except OSError as error:
            print(f"mocap-index: could not remember the refused files: {error}", file=sys.stderr)


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
            for worker in self.pool.free_slots():
                while len(worker.tasks) < TASKS_PER_WORKER and self.pending:
                    task = self.next_task(library)
                    if task:
                        self.pool.submit(worker, task)
            if self.pool.busy():
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


# ------------------------------------------------------------------- synthetic clips

SYNTHETIC = "synthetic"
SYNTHETIC_BATCH = 20_000


@dataclass(frozen=True)
class FillResult:
    added: int
    total: int
    seconds: float
    index_kinds: dict[str, str]


def fill_synthetic(
    settings: Settings,
    count: int,
    *,
    seed: int = 0,
    noise: float = 0.25,
    batch: int = SYNTHETIC_BATCH,
    report: Callable[[str], None] = print,
) -> FillResult:
    """Add synthetic clips until the library holds ``count`` clips (benchmarks at scale).

    Each synthetic clip copies the measurements (and windows) of a real clip of the library
    picked at random and gets its vectors plus Gaussian noise of ``noise`` standard deviations
    (per number, over the real clips), so the vectors cluster like real ones. They are named
    ``synthetic-<n>``, have the format and the label ``synthetic`` and no stored file; their
    content hash is the sha256 of ``synthetic:<seed>:<n>``. Rows go in in batches of
    ``batch`` (one transaction each) through the repository; the indexes (and window
    indexes) are rebuilt from the database at the end (an IVF index above
    ``MOCAP_INDEX_AUTO_THRESHOLD`` with ``auto``) and saved.
    """
    import hashlib
    from datetime import UTC, datetime

    import numpy as np

    from app.db import clips as clip_db
    from app.db import label_filters as label_db
    from app.db import vectors as vector_db
    from app.db import windows as window_db
    from app.db.session import checkpoint
    from app.services.library import open_library

    started = time.perf_counter()
    library = open_library(settings)
    try:
        descriptors = list(library.descriptors.values())
        with library.reads() as session:
            total = clip_db.count_clips(session)
            top = clip_db.max_clip_id(session)
            synthetic = set(label_db.clip_ids_with_label(session, SYNTHETIC).tolist())
            stored = {}
            for info in descriptors:
                ids, vectors = vector_db.load_vectors(
                    session, info.name, info.version, info.dimension
                )
                real = np.array([i not in synthetic for i in ids.tolist()], dtype=bool)
                stored[info.name] = dict(zip(ids[real].tolist(), vectors[real], strict=True))
            common = sorted(set.intersection(*(set(v) for v in stored.values())))
            centres = clip_db.get_clips(session, common)
            windows = {
                key: window_db.load_window_rows(session, key, common)
                for key in library.window_keys.values()
            }
        need = count - total
        if need <= 0:
            report(f"the library already holds {total} clips")
            return FillResult(0, total, time.perf_counter() - started, _kinds(library))
        rng = np.random.default_rng(seed)
        if common:
            centre_vectors = {
                name: np.stack([by_id[i] for i in common]) for name, by_id in stored.items()
            }
            records = [centres[i] for i in common]
        else:
            report("no real clip to start from: synthetic vectors are standard normal noise")
            centre_vectors = {
                info.name: rng.normal(size=(64, info.dimension)).astype(np.float32)
                for info in descriptors
            }
            records = []
        spread = {
            name: np.maximum(vectors.std(axis=0), 1e-3 * (np.abs(vectors).mean() + 1e-3))
            for name, vectors in centre_vectors.items()
        }
        versions = {info.name: info.version for info in descriptors}
        window_spread = {
            key: np.maximum(np.concatenate([v[2] for v in rows.values()]).std(axis=0), 1e-3)
            for key, rows in windows.items()
            if rows
        }
        report(
            f"adding {need} synthetic clips around {len(centre_vectors[descriptors[0].name])} "
            f"{'real clips' if common else 'random points'}"
        )
        done = 0
        while done < need:
            n = min(batch, need - done)
            pick = rng.integers(0, len(centre_vectors[descriptors[0].name]), size=n)
            noisy = {
                name: (
                    centre_vectors[name][pick]
                    + rng.normal(size=(n, centre_vectors[name].shape[1])) * spread[name] * noise
                ).astype(np.float32)
                for name in centre_vectors
            }
            now = datetime.now(UTC)
            rows = []
            for row in range(n):
                number = top + done + row + 1
                centre = records[int(pick[row])] if records else None
                rows.append(
                    clip_db.NewClip(
                        name=f"{SYNTHETIC}-{number:07d}",
                        format=SYNTHETIC,
                        content_hash=hashlib.sha256(
                            f"{SYNTHETIC}:{seed}:{number}".encode()
                        ).hexdigest(),
                        frame_count=centre.frame_count if centre else 300,
                        frame_time=centre.frame_time if centre else 1 / 30,
                        duration=centre.duration if centre else 10.0,
                        joint_count=centre.joint_count if centre else 25,
                        skeleton_family=SYNTHETIC,
                        lead_in_frames=0,
                        labels=(SYNTHETIC,),
                        files=(),
                        vectors={
                            name: vector_db.StoredVector(versions[name], noisy[name][row])
                            for name in noisy
                        },
                        created_at=now,
                        windows=_synthetic_windows(
                            windows, window_spread, centre.id if centre else None, rng, noise
                        ),
                    )
                )
            with library.writes.begin() as session:
                clip_db.insert_clips(session, rows)
            done += n
            report(f"  {done}/{need} clips ({time.perf_counter() - started:.0f} s)")
        checkpoint(library.engine)
        for info in descriptors:
            report(f"building the {info.name} index")
            library.rebuild_index(info.name)
        if library.window_keys:
            report("building the window indexes")
            library.rebuild_window_indexes()
        report("building the catalogue")
        library.rebuild_catalogue()
        with library.reads() as session:
            total = clip_db.count_clips(session)
        return FillResult(need, total, time.perf_counter() - started, _kinds(library))
    finally:
        library.close()


def _kinds(library: Library) -> dict[str, str]:
    every = {**library.indexes, **library.window_indexes}
    return {name: index.kind for name, index in every.items()}


def _synthetic_windows(
    windows: dict[Any, dict[int, tuple[Any, Any, Any]]],
    spread: dict[Any, Any],
    centre: int | None,
    rng: Any,
    noise: float,
) -> tuple[Any, ...]:
    """The windows of real clip ``centre``, their vectors plus noise (see fill_synthetic)."""
    import numpy as np

    from app.db import windows as window_db

    found = []
    for key, by_clip in windows.items():
        if centre is None or centre not in by_clip:
            continue
        starts, stops, vectors = by_clip[centre]
        noisy = vectors + rng.normal(size=vectors.shape) * spread[key] * noise
        found.append(
            window_db.NewWindows(
                name=key.name,
                version=key.version,
                lengths=np.full(len(starts), key.length),
                starts=starts,
                stops=stops,
                vectors=noisy.astype(np.float32),
            )
        )
    return tuple(found)
