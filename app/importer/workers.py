"""The import's worker processes: each reads, parses and describes the clips of its tasks
and sends back only the measurements, vectors and previews; a worker that dies costs its
task, retried clip by clip in a new one. Imports the motion core only (no SQLAlchemy or
FAISS)."""

from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from contextlib import suppress
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.discovery import ClipSource
from app.errors import MocapError
from app.motion.formats.gltf_pack import refers_to_files
from app.motion.model import ParseLimits
from app.services.describe import Description, MotionDescriber
from app.services.parser_pool import InlineParser
from app.services.upload_files import FolderFiles
from app.services.uploads import Upload

if TYPE_CHECKING:
    pass

MIN_ANIMATION_FRAMES = 5  # shorter animations of a multi-animation file are not imported
TASKS_PER_WORKER = 2  # in flight: one being described, one waiting
MAX_RESOURCE_BYTES = 256 * 1024 * 1024  # a .gltf's files, at most (as MOCAP_MAX_UPLOAD_BYTES)
WORKER_NICENESS = 5


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
    # A .gltf's .bin and textures are read from its folder (and below), only those it names.
    beside = source.motion.suffix.lower() == ".gltf" and refers_to_files(motion[1])
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
        resources=FolderFiles(source.motion.parent, MAX_RESOURCE_BYTES) if beside else None,
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
    :data:`MIN_ANIMATION_FRAMES` frames that moves a node (the default one when none does:
    the longest that moves, else the longest). An animation that moves nothing, such as the
    empty take an FBX SDK writes beside a real one, would be a held pose, not a clip; one that
    is a part of a take the file wrote split (``Animation.parts``) is in that take's clip."""
    first = describer.describe(upload, limits)
    if first.animation is None:
        return [first]
    described = {first.animation: first}
    parts = {part for animation in first.animations for part in animation.parts}
    for animation in first.animations:
        if (
            animation.frame_count < MIN_ANIMATION_FRAMES
            or not animation.moves
            or animation.name in described
            or animation.name in parts
        ):
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
    # The process that started this one: the importer when forked, else the fork server
    # (which exits with the importer). Either way it is gone when this one is re-parented; a
    # worker from the fork server compared its parent with the importer's id and quit at
    # its first idle second.
    started_by = os.getppid()
    while True:
        try:
            if not conn.poll(1.0):
                if os.getppid() != started_by:  # the importer is gone (killed)
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
        context.set_forkserver_preload(["app.importer.workers"])
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

    def submit(self, worker: _Worker, clips: list[TaskClip]) -> bool:
        """Send ``clips`` to ``worker``; False when it is gone (it died since the last
        :meth:`collect`, which replaces it): nothing was sent and its clips are no culprits."""
        self._next_task += 1
        try:
            worker.conn.send((self._next_task, clips))
        except (BrokenPipeError, OSError):
            return False
        worker.tasks[self._next_task] = clips
        return True

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
