"""Describing clips for the evaluation: parse, run the descriptors, cache the vectors.

Every clip found by :func:`app.discovery.discover` is parsed and run through
:func:`app.motion.pipeline.analyse` for the requested descriptors; FMDistance's 3-MAN numbers
(:func:`app.motion.descriptors.kinetic.three_man`) are kept too, for the maps. Vectors are
cached under ``cache_dir`` by content hash, descriptor name and descriptor version, plus a
fingerprint of the motion code (every ``app/motion/**/*.py``), so numbers computed by code
that changed without a version bump are never reused:
``<cache>/v1/<hash[:2]>/<hash>/<name>-v<version>-<code>.npy``. A second run only reads files.
With ``workers > 1`` clips are described in a process pool; a clip that fails (unreadable
file, unmappable skeleton, a crash in a worker) is skipped and reported, never stopping the
run.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import sys
import tempfile
import threading
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing.context import BaseContext
from pathlib import Path

import numpy as np

from app.cli.progress import ProgressBar
from app.discovery import ClipSource, content_hash
from app.errors import InvalidInput

CACHE_LAYOUT = "v1"
THREE_MAN = "three_man"


@dataclass(frozen=True)
class SkippedClip:
    path: Path
    reason: str


def descriptor_versions(names: Sequence[str]) -> dict[str, int]:
    from app.motion.descriptors import REGISTRY

    return {name: REGISTRY[name].version for name in names}


@functools.cache
def motion_code_fingerprint() -> str:
    """First 12 hex digits of the SHA-256 over the motion package's Python sources."""
    import app.motion

    root = Path(app.motion.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:12]


def _cache_keys(names: Sequence[str]) -> dict[str, str]:
    """Vector name -> cache file stem (the 3-MAN numbers follow the kinetic version)."""
    from app.motion.descriptors import REGISTRY

    code = motion_code_fingerprint()
    keys = {name: f"{name}-v{REGISTRY[name].version}-{code}" for name in names}
    keys[THREE_MAN] = f"{THREE_MAN}-kinetic-v{REGISTRY['kinetic'].version}-{code}"
    return keys


class VectorCache:
    """Descriptor vectors on disk by content hash, name and version; writes are atomic."""

    def __init__(self, root: Path | None) -> None:
        self.root = None if root is None else Path(root) / CACHE_LAYOUT

    def _path(self, digest: str, key: str) -> Path:
        assert self.root is not None
        return self.root / digest[:2] / digest / f"{key}.npy"

    def load(self, digest: str, keys: dict[str, str]) -> dict[str, np.ndarray] | None:
        """All of ``keys``' vectors for ``digest``, or ``None`` if any is missing or unreadable."""
        if self.root is None:
            return None
        found: dict[str, np.ndarray] = {}
        for name, key in keys.items():
            path = self._path(digest, key)
            try:
                found[name] = np.load(path, allow_pickle=False)
            except (OSError, ValueError):
                return None
        return found

    def store(self, digest: str, keys: dict[str, str], vectors: dict[str, np.ndarray]) -> None:
        if self.root is None:
            return
        for name, key in keys.items():
            path = self._path(digest, key)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                fd, temp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
                with os.fdopen(fd, "wb") as stream:
                    np.save(stream, np.asarray(vectors[name]), allow_pickle=False)
                os.replace(temp, path)
            except OSError as error:  # a read-only or full cache only costs time
                print(f"warning: cannot write the cache {path}: {error}", file=sys.stderr)
                return


def describe_source(
    kind: str, paths: tuple[str, ...], names: tuple[str, ...]
) -> tuple[dict[str, np.ndarray] | None, str | None]:
    """Parse and describe one clip (runs in a worker process).

    Returns ``(vectors, None)`` with the descriptors plus ``"three_man"``, or
    ``(None, reason)``; it never raises for a bad clip.
    """
    try:
        from app.motion.descriptors.kinetic import three_man
        from app.motion.formats import read_asf_amc, read_bvh
        from app.motion.pipeline import analyse

        data = [Path(p).read_bytes() for p in paths]
        motion = read_bvh(data[0]) if kind == "bvh" else read_asf_amc(data[0], data[1])
        analysis = analyse(motion, descriptors=list(names))
        vectors = dict(analysis.descriptors)
        vectors[THREE_MAN] = np.asarray(three_man(analysis.body), dtype=np.float64)
        return vectors, None
    except MemoryError:
        return None, "out of memory"
    except Exception as error:  # any failure of one clip must not stop the run
        detail = getattr(error, "detail", None) or str(error) or type(error).__name__
        if not isinstance(error, InvalidInput):
            detail = f"{type(error).__name__}: {detail}"
        return None, detail


ProgressCallback = Callable[[int], None]


@contextlib.contextmanager
def _progress_bar(total: int, enabled: bool) -> Iterator[ProgressCallback]:
    """The long commands' progress bar (:class:`app.cli.progress.ProgressBar`), advanced by
    the number of clips each call reports."""
    if not enabled or total == 0:
        yield lambda _n: None
        return
    bar = ProgressBar("describing clips")
    bar.start(total, workers=0)
    done = 0

    def advance(n: int) -> None:
        nonlocal done
        done += n
        bar.set_done(done)

    try:
        yield advance
    finally:
        bar.stop()


def _pool_context() -> BaseContext | None:
    import multiprocessing

    # forkserver: no fork of a process with threads (the progress bar's), cheap start-up.
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(["app.evaluation.describe", "app.motion.pipeline"])
        return context
    return None


Outcome = tuple[dict[str, np.ndarray] | None, str | None]


def _describe_parallel(
    jobs: list[tuple[int, ClipSource]],
    names: tuple[str, ...],
    workers: int,
    advance: ProgressCallback,
) -> dict[int, Outcome]:
    """Describe ``jobs`` in ``workers`` processes, one clip at a time per process.

    Each of ``workers`` threads owns a one-process pool and hands it one clip at a time, so
    a worker that dies (a crash in native code, the out-of-memory killer) costs exactly the
    clip it was describing: that pool is replaced and the thread carries on.
    """
    results: dict[int, Outcome] = {}
    queue = deque(jobs)
    lock = threading.Lock()
    stop = threading.Event()
    context = _pool_context()

    def work() -> None:
        pool: ProcessPoolExecutor | None = None
        try:
            while not stop.is_set():
                with lock:
                    if not queue:
                        return
                    i, source = queue.popleft()
                if pool is None:
                    pool = ProcessPoolExecutor(max_workers=1, mp_context=context)
                paths = tuple(map(str, source.paths))
                outcome: Outcome
                try:
                    outcome = pool.submit(describe_source, source.kind, paths, names).result()
                except BrokenProcessPool:
                    outcome = (None, "the worker process describing it died")
                    pool.shutdown(wait=False, cancel_futures=True)
                    pool = None
                except Exception as error:  # e.g. a result that cannot be unpickled
                    outcome = (None, f"{type(error).__name__}: {error}")
                with lock:
                    results[i] = outcome
                    advance(1)
        finally:
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)

    with ThreadPoolExecutor(max_workers=min(workers, len(jobs))) as threads:
        futures = [threads.submit(work) for _ in range(min(workers, len(jobs)))]
        try:
            for future in futures:
                future.result()
        except BaseException:
            stop.set()
            raise
    return results


def describe_clips(
    sources: Sequence[ClipSource],
    descriptors: Sequence[str],
    *,
    cache_dir: Path | None,
    workers: int = 1,
    progress: bool = True,
) -> tuple[list[tuple[ClipSource, str, dict[str, np.ndarray]]], list[SkippedClip]]:
    """Vectors of every clip (from the cache where possible), and the clips that failed.

    Returns ``[(source, content hash, {descriptor or "three_man": vector})]`` in the order of
    ``sources`` (failed clips left out) and the skipped clips with their reasons.
    """
    names = tuple(descriptors)
    keys = _cache_keys(names)
    cache = VectorCache(cache_dir)
    hashes: list[str | None] = []
    skipped: dict[int, SkippedClip] = {}
    described: dict[int, dict[str, np.ndarray]] = {}
    jobs: list[tuple[int, ClipSource]] = []
    for i, source in enumerate(sources):
        try:
            digest = content_hash(source)
        except OSError as error:
            hashes.append(None)
            skipped[i] = SkippedClip(source.motion, f"cannot read: {error.strerror}")
            continue
        hashes.append(digest)
        cached = cache.load(digest, keys)
        if cached is not None:
            described[i] = cached
        else:
            jobs.append((i, source))

    with _progress_bar(len(jobs), progress) as advance:
        if workers > 1 and len(jobs) > 1:
            results = _describe_parallel(jobs, names, workers, advance)
        else:
            results = {}
            for i, source in jobs:
                results[i] = describe_source(source.kind, tuple(map(str, source.paths)), names)
                advance(1)
    for i, source in jobs:
        vectors, reason = results.get(i, (None, "not described (interrupted)"))
        clip_hash = hashes[i]
        assert clip_hash is not None
        if vectors is None:
            skipped[i] = SkippedClip(source.motion, reason or "unknown error")
            continue
        kept = {name: np.asarray(vectors[name]) for name in keys}
        cache.store(clip_hash, keys, kept)
        described[i] = kept

    done = []
    for i, source in enumerate(sources):
        known = hashes[i]
        if i in described and known is not None:
            done.append((source, known, described[i]))
    return done, [skipped[i] for i in sorted(skipped)]
