"""Worker processes that run the FBX and glTF readers, so their crashes are nobody else's.

The FBX reader is C code (ufbx) behind a young Python binding with object-lifetime bugs, and
both formats are binary input from strangers. They are never read in the server process:
:class:`ParserPool` hands each file to one of a few reused worker processes and waits for the
:class:`ParsedScene` (plain numpy arrays, pickled back).

* A worker is started when first needed (at most ``size`` of them), kept for later files,
  and started anew when it dies.
* Per file: ``time_limit`` seconds, after which the worker is killed; ``memory_mb``
  megabytes of address space (``RLIMIT_AS``) above what the worker uses when idle.
* A crash, a hang, running out of memory: :class:`~app.errors.UnreadableFile` (422
  ``unreadable_file``) for that file, and nothing else notices. A worker that hit
  ``MemoryError`` exits after answering (its heap may be in pieces).
* The binding's objects are never freed in a worker (freeing them can crash it): a worker
  keeps every scene it read and retires after :data:`RETIRE_AFTER_FILES` files or half its
  memory budget, exiting without destructors; the pool starts another.
* The reader's own errors (ParseError, LimitExceeded) come back as themselves.
* A caller waits at most ``wait_limit`` seconds (default: one ``time_limit``) for a free
  worker, then gets :class:`~app.errors.ServiceBusy` (503 with Retry-After): a crowd of
  FBX/glTF requests is turned away instead of queueing without end.

Workers are spawned (not forked: the server process has threads) and import only the
motion core.
"""

from __future__ import annotations

import gc
import logging
import math
import multiprocessing
import os
import queue
import resource
import signal
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any, Protocol

from app.errors import (
    LimitExceeded,
    NoAnimation,
    ParseError,
    ServiceBusy,
    UnknownAnimation,
    UnreadableFile,
)
from app.motion.formats.scene_animation import Animation
from app.motion.model import Motion, ParseLimits

if TYPE_CHECKING:
    from app.config import Settings

log = logging.getLogger(__name__)

START_SECONDS = 60.0  # a worker's imports, on a busy machine
RETIRE_AFTER_FILES = 32  # a worker exits (and is replaced) after this many files
READY_SECONDS = 10.0  # a worker's tidying up after a file
FORMATS = ("fbx", "gltf", "fbx-rig", "gltf-rig")  # "-rig": a file without animation is a still
_START = "start"


@dataclass(frozen=True, eq=False)
class ParsedScene:
    """What a worker sends back: the motion of one animation and the file's animations."""

    motion: Motion
    animations: tuple[Animation, ...]
    animation: str


def parse_scene(
    kind: str,
    data: bytes,
    animation: str | None,
    limits: ParseLimits,
    keep: list[Any] | None = None,
) -> ParsedScene:
    """Read one animation of an FBX (``kind="fbx"``) or glTF file, in this process
    (``keep``: see :func:`~app.motion.formats.fbx.read_fbx`); ``"fbx-rig"`` and
    ``"gltf-rig"`` read a file without animation as its rest pose (a rig)."""
    kind, _, mode = kind.partition("-")
    still = mode == "rig"
    if kind == "fbx":
        from app.motion.formats.fbx import read_fbx

        motion, animations, chosen = read_fbx(
            data, animation=animation, limits=limits, keep=keep, still=still
        )
    elif kind == "gltf":
        from app.motion.formats.gltf import read_gltf

        motion, animations, chosen = read_gltf(
            data, animation=animation, limits=limits, still=still
        )
    else:
        raise ValueError(f"unknown scene format {kind!r}")
    return ParsedScene(motion, tuple(animations), chosen)


class SceneParser(Protocol):
    def parse(
        self, kind: str, data: bytes, *, animation: str | None, limits: ParseLimits
    ) -> ParsedScene:
        """Read one animation of an FBX/glTF file (ParseError, LimitExceeded,
        UnreadableFile)."""
        ...


class InlineParser:
    """The readers run in *this* process, under the pool's limits: for processes that are
    expendable workers already (the bulk import's, whose deaths cost one clip).

    Time: a real-time timer whose SIGALRM, left to its default action, ends the process
    even inside C code. Memory: the soft ``RLIMIT_AS`` lowered for the read, then restored.
    """

    def __init__(self, *, time_limit: float | None = 30.0, memory_mb: int | None = 1024):
        self.time_limit = time_limit
        self.memory_mb = memory_mb

    def parse(
        self, kind: str, data: bytes, *, animation: str | None, limits: ParseLimits
    ) -> ParsedScene:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        if self.memory_mb is not None:
            wanted = _address_space() + self.memory_mb * 1024 * 1024
            if hard != resource.RLIM_INFINITY:
                wanted = min(wanted, hard)
            resource.setrlimit(resource.RLIMIT_AS, (wanted, hard))
        previous = signal.signal(signal.SIGALRM, signal.SIG_DFL)
        if self.time_limit is not None:
            signal.setitimer(signal.ITIMER_REAL, self.time_limit)
        try:
            return parse_scene(kind, data, animation, limits)
        except (ParseError, LimitExceeded):
            raise
        except MemoryError:
            raise UnreadableFile(
                f"reading the file needed more than {self.memory_mb} MB "
                "(MOCAP_PARSER_MEMORY_MB); it cannot be read"
            ) from None
        except RecursionError:
            raise UnreadableFile("the file is nested too deeply to read") from None
        except Exception as error:  # a reader bug on odd input: that file is unreadable
            raise UnreadableFile(
                f"the reader failed ({type(error).__name__}); the file cannot be read"
            ) from None
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _address_space() -> int:
    """Bytes of address space this process maps now."""
    with open("/proc/self/statm") as stream:
        return int(stream.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def serve_requests(
    conn: Connection,
    memory_mb: int | None,
    answer_for: Callable[[tuple[Any, ...]], tuple[Any, ...]],
    *,
    retire_after: int,
    keep: Callable[[tuple[Any, ...]], None] = lambda _request: None,
) -> None:
    """The worker's side of the pool's protocol, once its imports are done.

    Limits the address space to ``memory_mb`` above what the worker maps now, says "ready",
    then answers each request ``(kind, data, animation, limits)`` with ``answer_for(request)``
    until the pipe closes, ``keep(request)`` after each answer (what must outlive it), and
    after each one says "ready" again, or "retire" and exits after ``retire_after`` requests
    or half its memory budget. ``MemoryError`` answers ``("memory", None)`` and exits (the
    heap may be in pieces); exits skip destructors.
    """
    baseline = _address_space()
    if memory_mb is not None and hasattr(resource, "RLIMIT_AS"):
        limit = baseline + memory_mb * 1024 * 1024
        with suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    conn.send(("ready", os.getpid()))
    done = 0
    while True:
        try:
            request = conn.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        exit_after = False
        answer: tuple[Any, ...]
        try:
            answer = answer_for(request)
        except MemoryError:
            answer = ("memory", None)
            exit_after = True
        try:
            conn.send(answer)
        except MemoryError:
            exit_after = True
            with suppress(Exception):
                conn.send(("memory", None))
        except (BrokenPipeError, OSError):
            return
        del answer
        if exit_after:
            os._exit(0)
        keep(request)
        del request
        done += 1
        retire = done >= retire_after or (
            memory_mb is not None and _address_space() > baseline + memory_mb * 2**19
        )
        try:
            conn.send(("retire" if retire else "ready", None))
        except (BrokenPipeError, OSError):
            return
        if retire:
            os._exit(0)


def _parse_answer(request: tuple[Any, ...], kept: list[Any]) -> tuple[Any, ...]:
    """The answer to ``(kind, data, animation, limits)``: the scene, or the reader's error."""
    kind, data, animation, limits = request
    try:
        return ("ok", parse_scene(kind, data, animation, limits, kept))
    except UnknownAnimation as error:
        return ("unknown_animation", error.reason, None)
    except ParseError as error:
        return ("parse_error", error.reason, error.line, error.code)
    except LimitExceeded as error:
        return ("limit", error.detail)
    except MemoryError:
        raise
    except RecursionError:
        return ("unreadable", "the file is nested too deeply to read")
    except Exception as error:  # a reader bug on odd input: that file is unreadable
        return ("unreadable", f"the reader failed ({type(error).__name__})")


def _worker_main(conn: Connection, memory_mb: int | None) -> None:
    """Answer requests ``(kind, data, animation, limits)`` until the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the server to handle
    import numpy  # noqa: F401 - import before measuring the baseline address space

    import app.motion.formats.fbx
    import app.motion.formats.gltf  # noqa: F401

    with suppress(ImportError):
        import ufbx  # noqa: F401
    # The cyclic garbage collector crashes on the binding's objects once scenes are kept
    # alive (below); nothing here needs it, and the worker retires before it matters.
    gc.disable()
    # Scenes are never freed here (freeing the binding's objects can crash it, and a scene
    # may point into the file's bytes): they are kept, with the bytes, until the worker
    # retires after RETIRE_AFTER_FILES files or half its memory budget, and exits without
    # running destructors.
    kept: list[Any] = []  # loaded scenes
    kept_bytes: list[bytes] = []
    serve_requests(
        conn,
        memory_mb,
        lambda request: _parse_answer(request, kept),
        retire_after=RETIRE_AFTER_FILES,
        keep=lambda request: kept_bytes.append(request[1]),
    )


@dataclass(eq=False)
class _Worker:
    process: Any
    conn: Connection
    pid: int
    needs_ready: bool = False
    busy_since: float | None = field(default=None)


class ParserPool:
    """Up to ``size`` reused worker processes reading FBX/glTF files (see module docstring).

    Thread-safe: each call borrows an idle worker (waiting for one when all are busy).
    A subclass may run other work in its workers: ``worker_main`` (the process's loop,
    answering ``(kind, data, animation, limits)`` requests as :func:`_worker_main` does) and
    ``kinds`` (the request kinds it takes).
    """

    worker_main: Callable[[Connection, int | None], None] = staticmethod(_worker_main)
    kinds: tuple[str, ...] = FORMATS

    def __init__(
        self,
        size: int = 2,
        *,
        time_limit: float | None = 30.0,
        memory_mb: int | None = 1024,
        wait_limit: float | None = None,
    ) -> None:
        self.size = max(1, size)
        self.time_limit = time_limit
        self.memory_mb = memory_mb
        # A worker frees up within one time limit unless every one is stuck on a hostile file.
        self.wait_limit = time_limit if wait_limit is None else wait_limit
        self._context = multiprocessing.get_context("spawn")
        # Idle workers, and a _START token per worker slot not yet filled (LIFO: a warm
        # worker is taken before a new one is started); None once closed.
        self._idle: queue.LifoQueue[_Worker | str | None] = queue.LifoQueue()
        for _ in range(self.size):
            self._idle.put(_START)
        self._lock = threading.Lock()
        self._workers: list[_Worker] = []
        self._closed = False
        self.crashes = 0  # workers lost mid-file (crash, hang, out of memory)

    @classmethod
    def from_settings(cls, settings: Settings) -> ParserPool:
        """MOCAP_PARSER_WORKERS, MOCAP_PARSER_TIMEOUT_SECONDS, MOCAP_PARSER_MEMORY_MB."""
        return cls(
            settings.parser_workers,
            time_limit=settings.parser_timeout_seconds,
            memory_mb=settings.parser_memory_mb,
        )

    # -- workers ------------------------------------------------------------------------

    def _spawn(self) -> _Worker:
        ours, theirs = self._context.Pipe()
        process = self._context.Process(
            target=self.worker_main,
            args=(theirs, self.memory_mb),
            name="mocap-parser",
            daemon=True,
        )
        process.start()
        theirs.close()
        try:
            if not ours.poll(START_SECONDS):
                raise UnreadableFile("the file reader did not start in time; try again")
            _, pid = ours.recv()
        except (EOFError, OSError):
            process.join(timeout=1)
            raise UnreadableFile("the file reader could not start; try again") from None
        except UnreadableFile:
            process.kill()
            process.join()
            raise
        worker = _Worker(process, ours, int(pid))
        with self._lock:
            self._workers.append(worker)
        return worker

    def _borrow(self) -> _Worker:
        try:
            item = self._idle.get(timeout=self.wait_limit)
        except queue.Empty:
            raise ServiceBusy(
                f"all {self.size} FBX/glTF file readers are busy (MOCAP_PARSER_WORKERS) and "
                f"none freed up in {self.wait_limit:g} s; try again in a few seconds",
                retry_after=math.ceil(self.wait_limit or 1),
            ) from None
        if item is None or self._closed:
            self._idle.put(None)
            raise UnreadableFile("the service is shutting down")
        if isinstance(item, _Worker):
            return item
        try:
            return self._spawn()
        except BaseException:
            self._idle.put(_START)
            raise

    def _discard(self, worker: _Worker) -> None:
        """Stop ``worker`` for good (its slot frees up for a new one)."""
        with suppress(Exception):
            worker.process.kill()
        with suppress(Exception):
            worker.process.join(timeout=5)
        with suppress(Exception):
            worker.conn.close()
        with self._lock:
            if worker in self._workers:
                self._workers.remove(worker)
        self._idle.put(_START)

    def _ready(self, worker: _Worker) -> bool:
        """Wait for the worker's "ready" after its previous file (False: it died)."""
        if not worker.needs_ready:
            return worker.process.is_alive()
        try:
            if worker.conn.poll(READY_SECONDS):
                message = worker.conn.recv()
                worker.needs_ready = message[0] != "ready"
                return not worker.needs_ready and worker.process.is_alive()
        except (EOFError, OSError):
            pass
        return False

    def pids(self) -> list[int]:
        """Process ids of the live workers."""
        with self._lock:
            return [w.pid for w in self._workers]

    def busy_pids(self) -> list[int]:
        """Process ids of the workers reading a file right now."""
        with self._lock:
            return [w.pid for w in self._workers if w.busy_since is not None]

    # -- reading ------------------------------------------------------------------------

    def parse(
        self, kind: str, data: bytes, *, animation: str | None, limits: ParseLimits
    ) -> ParsedScene:
        """Read one animation of ``data`` in a worker.

        Raises
        ------
        ParseError, LimitExceeded
            The reader refused the file.
        UnreadableFile
            The worker crashed, ran out of time or memory.
        """
        if kind not in self.kinds:
            raise ValueError(f"unknown scene format {kind!r}")
        for _ in range(self.size + 1):  # an idle worker may have died since its last file
            worker = self._borrow()
            if self._ready(worker):
                break
            self._discard(worker)
        else:
            raise UnreadableFile("the file readers keep failing to start; try again")
        try:
            worker.busy_since = time.monotonic()
            worker.conn.send((kind, data, animation, limits))
            if not worker.conn.poll(self.time_limit):
                self._lost(worker)
                raise UnreadableFile(
                    f"reading the file took longer than {self.time_limit:g} s "
                    "(MOCAP_PARSER_TIMEOUT_SECONDS); it cannot be read"
                )
            answer = worker.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            self._lost(worker)
            raise UnreadableFile(
                "the file reader crashed on this file; it is damaged or not a motion file"
            ) from None
        worker.busy_since = None
        worker.needs_ready = True
        status = answer[0]
        if status == "memory":
            self._discard(worker)
            raise UnreadableFile(
                f"reading the file needed more than {self.memory_mb} MB "
                "(MOCAP_PARSER_MEMORY_MB); it cannot be read"
            )
        self._idle.put(worker)
        if status == "ok":
            parsed: ParsedScene = answer[1]
            return parsed
        if status == "unknown_animation":
            raise UnknownAnimation(answer[1])
        if status == "parse_error":
            if answer[3] == NoAnimation.code:  # a rig: readable, with no motion
                raise NoAnimation(answer[1], line=answer[2])
            raise ParseError(answer[1], line=answer[2])
        if status == "limit":
            raise LimitExceeded(answer[1])
        raise UnreadableFile(f"{answer[1]}; the file cannot be read")

    def _lost(self, worker: _Worker) -> None:
        self.crashes += 1
        log.warning("a file reader process (pid %d) died or hung; starting anew", worker.pid)
        self._discard(worker)

    def close(self) -> None:
        """Stop every worker (idle ones politely, busy ones are killed)."""
        with self._lock:
            self._closed = True
            workers = list(self._workers)
        self._idle.put(None)
        for worker in workers:
            with suppress(Exception):
                worker.conn.send(None)
        deadline = time.monotonic() + 2
        for worker in workers:
            with suppress(Exception):
                worker.process.join(timeout=max(0.0, deadline - time.monotonic()))
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join()
            with suppress(Exception):
                worker.conn.close()
        with self._lock:
            self._workers = []
