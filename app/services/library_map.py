"""The library as the browser UI shows it: a 2-D map and a filtered list (the stick-figure
previews are in :mod:`app.services.previews`).

Map (:func:`library_map`)
    For every clip two 2-D views, both from the *stored* vectors (no clip is re-read):

    * FMDistance's 3-MAN features (Onuma et al. 2008, eq. 5) — total kinetic energy
      ``e_all``, upper/lower ratio ``r_u/l`` and limbs/trunk ratio ``r_l/t`` — computed
      from the stored ``kinetic`` vector by
      :func:`~app.services.map_geometry.three_man_from_kinetic` (the vector is ``log1p`` of
      the mean energies, so ``expm1`` gives them back);
    * the first two principal components of the chosen descriptor's vectors (centred, not
      scaled: the map keeps the Euclidean geometry searches use).

    A clip is an ``outlier`` when it is isolated under the chosen descriptor: its mean
    distance to its :data:`OUTLIER_NEIGHBOURS` nearest other clips has a modified z-score
    (Iglewicz and Hoaglin: median and MAD, so the outliers do not hide themselves) above
    :data:`OUTLIER_Z`. (The distance to the library's median vector was tried first: it
    marks whole minority classes — every dash among walks — rather than odd clips.)

    The numbers (3-MAN features, PCA-2D, isolation, the random-projection forest that keeps
    the work at N log N) are in :mod:`app.services.map_geometry`. :class:`LibraryMap`
    computes a layout once per change of the library, one at a time, in the background for
    a large library (serving the last one meanwhile); bench/bench_map.py measures it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.db import browsing as browse_db
from app.db import clips as clip_db
from app.db import label_filters as label_db
from app.db import vectors as vector_db
from app.db.changes import latest_seq
from app.motion.descriptors import kinetic
from app.services.library import Library
from app.services.map_geometry import (
    KINETIC_DIMENSION,
    OUTLIER_NEIGHBOURS,
    OUTLIER_Z,
    Projection,
    isolation_scores,
    modified_z_scores,
    pca_2d,
    three_man_many,
)

log = logging.getLogger(__name__)


def _encode(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()


# -- map ------------------------------------------------------------------------------------

THREE_MAN_DESCRIPTOR = kinetic.DESCRIPTOR.name
MAP_WAIT_SECONDS = 1.0
"""A layout computed in less than this is waited for; a slower one (a large library) is
recomputed in the background while requests get the last one (:class:`LibraryMap`)."""
MAP_MAX_AGE_SECONDS = 60.0
"""An encoded map is reused while the library shows no change, at most this long (names and
labels another process changed show within it)."""


@dataclass(frozen=True)
class Layout:
    """What the map computes from one descriptor's vectors (and the kinetic ones, for the
    3-MAN features); clip ids ascending."""

    ids: np.ndarray  # (N,) clips with a current vector of the descriptor
    projection: Projection
    outlier_scores: np.ndarray  # (N,) modified z-scores of the isolation
    outliers: np.ndarray  # (N,) bool
    three_man_ids: np.ndarray  # (M,) clips with a current, finite kinetic vector
    three_man: np.ndarray  # (M, 3)
    inputs: bytes = b""  # digest of the vectors it was computed from


def vector_layout(vectors: np.ndarray) -> tuple[Projection, np.ndarray]:
    """PCA-2D and the modified z-scores of the isolation of ``(N, D)`` vectors."""
    n = vectors.shape[0]
    scores = modified_z_scores(isolation_scores(vectors)) if n >= 3 else np.zeros(n)
    return pca_2d(vectors), scores


def three_man_available(library: Library) -> bool:
    info = library.descriptors.get(THREE_MAN_DESCRIPTOR)
    return info is not None and info.dimension == KINETIC_DIMENSION


def compute_layout(library: Library, descriptor: str, last: Layout | None = None) -> Layout:
    """Read the stored vectors and lay the library out (the slow part of the map); ``last``
    when it was computed from the same vectors (the feed also moves for renames and
    relabels, which change no vector)."""
    info = library.descriptor(descriptor)
    kinetic_info = library.descriptors.get(THREE_MAN_DESCRIPTOR)
    with library.reads() as session:
        ids, vectors = vector_db.load_vectors(session, info.name, info.version, info.dimension)
        if three_man_available(library) and kinetic_info is not None:
            if kinetic_info.name == info.name:
                kinetic_ids, kinetic_vectors = ids, vectors
            else:
                kinetic_ids, kinetic_vectors = vector_db.load_vectors(
                    session, kinetic_info.name, kinetic_info.version, kinetic_info.dimension
                )
        else:
            kinetic_ids, kinetic_vectors = np.zeros(0, np.int64), np.zeros((0, 0), np.float32)
    digest = hashlib.blake2b(digest_size=16)
    for array in (ids, vectors, kinetic_ids, kinetic_vectors):
        digest.update(np.ascontiguousarray(array).tobytes())
    inputs = digest.digest()
    if last is not None and last.inputs == inputs:
        return last
    projection, scores = vector_layout(vectors)
    features = three_man_many(kinetic_vectors) if len(kinetic_ids) else np.zeros((0, 3))
    finite = np.all(np.isfinite(features), axis=1)
    return Layout(
        ids, projection, scores, np.asarray(scores > OUTLIER_Z), kinetic_ids[finite],
        features[finite], inputs,
    )  # fmt: skip


def map_payload(library: Library, descriptor: str, layout: Layout) -> dict[str, Any]:
    """Every clip with its 3-MAN features, the PCA-2D of ``descriptor`` and an outlier flag
    (from ``layout``), and its name, labels, format, duration and frames (read now).

    A clip without a current vector of a descriptor — or stored after ``layout`` was
    computed — gets ``null`` for that view.
    """
    info = library.descriptor(descriptor)
    with library.reads() as session:
        summaries = browse_db.clip_summaries(session)
    projection = layout.projection
    # Round whole arrays once; per-clip work is then dictionary look-ups only.
    id_list = layout.ids.tolist()
    pca_by_id = dict(zip(id_list, np.round(projection.points, 5).tolist(), strict=True))
    outlier_by_id = dict(zip(id_list, layout.outliers.tolist(), strict=True))
    score_by_id = dict(zip(id_list, np.round(layout.outlier_scores, 2).tolist(), strict=True))
    three_man_by_id = dict(
        zip(layout.three_man_ids.tolist(), np.round(layout.three_man, 5).tolist(), strict=True)
    )
    clips = []
    for summary in summaries:
        clip_id = summary.id
        man = three_man_by_id.get(clip_id)
        clips.append(
            {
                "id": clip_id,
                "name": summary.name,
                "labels": list(summary.labels),
                "format": summary.format,
                "duration": round(float(summary.duration), 3),
                "frame_count": summary.frame_count,
                "x": None if man is None else man[0],
                "y": None if man is None else man[1],
                "three_man": man,
                "pca": pca_by_id.get(clip_id),
                "outlier": outlier_by_id.get(clip_id, False),
                "outlier_score": score_by_id.get(clip_id),
            }
        )
    return {
        "descriptor": info.name,
        "count": len(clips),
        "three_man_available": three_man_available(library),
        "three_man_axes": ["e_all", "r_u/l", "r_l/t"],
        "pca_explained_variance": [round(v, 4) for v in projection.explained],
        "outlier_rule": (
            f"isolation = mean {info.name} distance to the {OUTLIER_NEIGHBOURS} nearest other "
            f"clips; outlier when its modified z-score (median/MAD) is over {OUTLIER_Z}"
        ),
        "clips": clips,
    }


def library_map(library: Library, descriptor: str) -> dict[str, Any]:
    """The map of ``descriptor`` computed now (no cache: see :class:`LibraryMap`)."""
    return map_payload(library, descriptor, compute_layout(library, descriptor))


@dataclass
class _Computed:
    layout: Layout
    feed: int  # the change feed's last row when the computation started
    finished: float  # time.monotonic()
    seconds: float


@dataclass
class _Encoded:
    key: tuple[int, int, int]  # the feed, this process's edits, the layout's feed
    made: float  # time.monotonic()
    seconds: float  # how long the answer took (its layout's computation included)
    body: bytes


class LibraryMap:
    """``GET /map`` of one application: each descriptor's layout computed once per change
    of the library, one computation at a time in a thread of its own (single flight), and
    each answer encoded once.

    The change feed's last row (:func:`app.db.changes.latest_seq`: clips stored or deleted,
    vectors changed, by any process) tells when the layout is out of date. Work that took
    less than :data:`MAP_WAIT_SECONDS` the last time is waited for; slower work (a large
    library) is redone in the background while requests get the last answer: a layout no
    sooner than twice its time after the last one ended (at most a third of a core), an
    answer (names, labels: an O(N) read and encoding) once per change. An answer is reused
    while nothing changed (this process's renames and relabels count: ``Library.edits``),
    for at most :data:`MAP_MAX_AGE_SECONDS` (renames by other processes).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._layouts: dict[str, _Computed] = {}
        self._running: dict[str, Future[_Computed]] = {}
        self._encoded: dict[str, _Encoded] = {}
        self._encoding: dict[str, threading.Lock] = {}
        self._encoding_behind: set[str] = set()

    def body(self, library: Library, descriptor: str) -> bytes:
        """The encoded map of ``descriptor`` (JSON)."""
        library.descriptor(descriptor)  # 422 for an unknown one, before anything runs
        with library.reads() as session:
            feed = latest_seq(session)
        with self._lock:
            waiting = self._ensure_layout(library, descriptor, feed)
        if waiting is not None:
            waiting.result()
        with self._lock:
            layout = self._layouts[descriptor]
            key = (feed, library.edits, layout.feed)
            encoded = self._encoded.get(descriptor)
            if encoded is not None:
                fresh = time.monotonic() - encoded.made < MAP_MAX_AGE_SECONDS
                if encoded.key == key and fresh:
                    return encoded.body
                if encoded.seconds > MAP_WAIT_SECONDS:  # slow: the last answer, meanwhile
                    if descriptor not in self._encoding_behind:
                        self._encoding_behind.add(descriptor)
                        threading.Thread(
                            target=self._encode_behind,
                            args=(library, descriptor, key, layout),
                            name="mocap-map",
                            daemon=True,
                        ).start()
                    return encoded.body
        return self._encode(library, descriptor, key, layout)

    def _ensure_layout(
        self, library: Library, descriptor: str, feed: int
    ) -> Future[_Computed] | None:
        """Start computing the layout when it is out of date (the caller holds the lock);
        returns the computation to wait for, or None when the last layout serves."""
        last = self._layouts.get(descriptor)
        if last is not None and last.feed == feed:
            return None
        running = self._running.get(descriptor)
        slow = last is not None and last.seconds > MAP_WAIT_SECONDS
        if running is None:
            soon = last is not None and time.monotonic() - last.finished < 2 * last.seconds
            if not (slow and soon):
                running = self._start(library, descriptor, feed)
        return None if slow else running

    def _encode(
        self, library: Library, descriptor: str, key: tuple[int, int, int], layout: _Computed
    ) -> bytes:
        """Encode the answer once: requests arriving meanwhile take this one."""
        with self._lock:
            encoding = self._encoding.setdefault(descriptor, threading.Lock())
        with encoding:
            with self._lock:
                encoded = self._encoded.get(descriptor)
            if encoded is not None and encoded.key == key:
                return encoded.body
            started = time.monotonic()
            body = _encode(map_payload(library, descriptor, layout.layout))
            now = time.monotonic()
            took = now - started + (layout.seconds if layout.feed == key[0] else 0.0)
            with self._lock:
                self._encoded[descriptor] = _Encoded(key, now, took, body)
        return body

    def _encode_behind(
        self, library: Library, descriptor: str, key: tuple[int, int, int], layout: _Computed
    ) -> None:
        try:
            self._encode(library, descriptor, key, layout)
        except Exception:  # the next request tries again
            log.exception("encoding the map failed")
        finally:
            with self._lock:
                self._encoding_behind.discard(descriptor)

    def _start(self, library: Library, descriptor: str, feed: int) -> Future[_Computed]:
        """Compute the layout in a thread of its own (the caller holds the lock)."""
        future: Future[_Computed] = Future()
        self._running[descriptor] = future
        last = self._layouts.get(descriptor)

        def compute() -> None:
            started = time.monotonic()
            try:
                layout = compute_layout(library, descriptor, last.layout if last else None)
            except BaseException as error:
                with self._lock:
                    self._running.pop(descriptor, None)
                future.set_exception(error)
                return
            now = time.monotonic()
            done = _Computed(layout, feed, now, now - started)
            with self._lock:
                self._layouts[descriptor] = done
                self._running.pop(descriptor, None)
            future.set_result(done)

        threading.Thread(target=compute, name="mocap-map", daemon=True).start()
        return future


# -- filtered list --------------------------------------------------------------------------


def find_clips(
    library: Library, *, q: str | None, label: label_db.LabelFilter, limit: int, offset: int
) -> tuple[list[clip_db.ClipRecord], int]:
    """One page (id order) of the clips whose name contains ``q`` (case-insensitive) and
    that carry every label of ``label``; and how many match in total."""
    with library.reads() as session:
        page_ids, total = browse_db.find_clip_ids(
            session, name_contains=q, label=label, limit=limit, offset=offset
        )
        found = clip_db.get_clips(session, page_ids)
    return [found[i] for i in page_ids if i in found], total


def label_counts(library: Library) -> list[tuple[str, int]]:
    """Every label in use with its number of clips, most used first."""
    with library.reads() as session:
        return browse_db.label_counts(session)


def licence_counts(library: Library) -> list[tuple[str, int]]:
    """Every licence in use with its number of clips, most used first."""
    with library.reads() as session:
        return browse_db.licence_counts(session)
