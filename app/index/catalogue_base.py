"""The catalogue's base: every clip of a catalogue file as columns, shared by mapping.

A :class:`CatalogueBase` holds the clips sorted by id, each clip's entry one orjson-encoded
list (:func:`encode_entry`; decoded when a search shows it, ~2 us), frame counts and frame
times as columns, the clips of each label key, and the coded fields (:data:`CODED`) as
columns of codes into a table of their values. Built from entries or from the arrays of a
catalogue file (:mod:`app.index.array_file`, memory-mapped: every server process of one
machine shares one copy), merged with an overlay of changed clips into a new base. The
catalogue itself — the overlay, the change feed, the file — is :mod:`app.index.catalogue`.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from functools import cached_property
from typing import Any

import numpy as np
import orjson

from app.db.clips import AnimationRecord
from app.db.entries import ClipEntry

EPOCH = datetime(1970, 1, 1, tzinfo=UTC)
ROW_BITS = 10  # ids sharing their bits above these are found from one entry of a row table
MAX_ROW_BUCKETS = 1 << 16  # ... of at most this many entries (ids up to 67 M); else a search


def _micros(value: datetime) -> int:
    delta = value - EPOCH
    return (delta.days * 86_400 + delta.seconds) * 1_000_000 + delta.microseconds


def encode_entry(entry: ClipEntry) -> bytes:
    """One clip as stored in the catalogue file: an orjson list of its fields after the id (the
    row's), in :class:`ClipEntry` order, ``created_at`` in microseconds since 1970."""
    fields: list[Any] = list(entry[1:])
    fields[-2] = (
        None
        if entry.animations is None
        else [[a.name, a.frame_count, a.duration, a.selected] for a in entry.animations]
    )
    fields[-1] = _micros(entry.created_at)
    return orjson.dumps(fields)


def decode_entry(clip_id: int, data: bytes | memoryview) -> ClipEntry:
    fields = orjson.loads(data)  # the fields after the id, in ClipEntry order
    fields[2], fields[4], fields[13] = tuple(fields[2]), tuple(fields[4]), tuple(fields[13])
    if fields[14] is not None:
        fields[14] = tuple([AnimationRecord(n, f, d, s) for n, f, d, s in fields[14]])
    fields[15] = EPOCH + timedelta(microseconds=fields[15])
    # The tuple made directly: a search decodes a dozen, and ClipEntry._make's checks (and
    # inserting the id in front) cost a third of a decode.
    return _new_tuple(ClipEntry, (clip_id, *fields))


_new_tuple = tuple.__new__


def _int64_view(array: np.ndarray) -> memoryview:
    """``array`` ``(N,)`` int64 as a view whose items are Python ints (a dozen reads per search:
    half the cost of numpy's scalars)."""
    return np.ascontiguousarray(array, np.int64).data.cast("B").cast("q")


# Fields of an entry kept as columns of codes into a table of their values, so a filter on
# them (licence, source) tests each value once, not each clip.
CODED = ("source", "licence")


@dataclass(frozen=True)
class CatalogueBase:
    """The clips of a file (or of a compaction): ids ``(N,)`` sorted, each clip's encoded
    entry ``blob[offsets[i]:offsets[i + 1]]``, ``frame_counts`` and ``frame_times`` ``(N,)``;
    for each label key the rows ``key_rows[key]`` of ``label_ids`` listing its clips; for each
    field of :data:`CODED` the codes ``(N,)`` int32 of each clip's value in its table (-1:
    None)."""

    ids: np.ndarray
    offsets: np.ndarray
    blob: np.ndarray
    frame_counts: np.ndarray
    frame_times: np.ndarray
    label_ids: np.ndarray
    key_rows: dict[str, tuple[int, int]]
    codes: dict[str, np.ndarray]
    tables: dict[str, list[str]]

    @classmethod
    def build(cls, entries: Iterable[ClipEntry]) -> CatalogueBase:
        """A base holding ``entries`` (any order; one per id)."""
        return cls.empty().merged({e.id: e for e in entries})

    @classmethod
    def empty(cls) -> CatalogueBase:
        nothing = np.zeros(0, np.int64)
        return cls(
            ids=nothing,
            offsets=np.zeros(1, np.int64),
            blob=np.zeros(0, np.uint8),
            frame_counts=nothing,
            frame_times=np.zeros(0, np.float64),
            label_ids=nothing,
            key_rows={},
            codes={name: np.zeros(0, np.int32) for name in CODED},
            tables={name: [] for name in CODED},
        )

    def merged(self, overlay: Mapping[int, ClipEntry | None]) -> CatalogueBase:
        """This base with ``overlay`` applied (clip id -> its entry now, None: deleted). Rows
        the overlay does not touch keep their encoded bytes and columns as they are."""
        touched = np.fromiter(overlay, np.int64, count=len(overlay))
        kept = np.flatnonzero(~np.isin(self.ids, touched))
        added = sorted((i, e) for i, e in overlay.items() if e is not None)
        ids = np.concatenate([self.ids[kept], np.fromiter((i for i, _ in added), np.int64)])
        order = np.argsort(ids, kind="stable")
        blob = self.blob.data
        encoded: list[bytes | memoryview] = [
            blob[a:b]
            for a, b in zip(
                self.offsets[kept].tolist(), self.offsets[kept + 1].tolist(), strict=True
            )
        ]
        encoded += [encode_entry(e) for _, e in added]
        offsets = np.zeros(ids.size + 1, np.int64)
        np.cumsum(np.fromiter((len(encoded[i]) for i in order.tolist()), np.int64), out=offsets[1:])
        frame_counts = np.concatenate(
            [self.frame_counts[kept], np.array([e.frame_count for _, e in added], np.int64)]
        )
        frame_times = np.concatenate(
            [self.frame_times[kept], np.array([e.frame_time for _, e in added], np.float64)]
        )
        keyed: dict[str, np.ndarray] = {}
        for key in self.key_rows:
            base = self.with_key(key)
            keyed[key] = base[~np.isin(base, touched)] if touched.size else base
        fresh: dict[str, list[int]] = {}
        for clip_id, entry in added:
            for key in entry.label_keys():
                fresh.setdefault(key, []).append(clip_id)
        for key, more in fresh.items():
            keyed[key] = np.union1d(keyed.get(key, np.zeros(0, np.int64)), more)
        keys = sorted(k for k, v in keyed.items() if v.size)
        bounds = np.zeros(len(keys) + 1, np.int64)
        np.cumsum([keyed[k].size for k in keys], out=bounds[1:])
        codes: dict[str, np.ndarray] = {}
        tables: dict[str, list[str]] = {}
        for name in CODED:
            table = list(self.tables[name])
            index = {value: code for code, value in enumerate(table)}
            new_codes = []
            for _, entry in added:
                value = getattr(entry, name)
                if value is None:
                    new_codes.append(-1)
                    continue
                if value not in index:
                    index[value] = len(table)
                    table.append(value)
                new_codes.append(index[value])
            column = np.concatenate([self.codes[name][kept], np.array(new_codes, np.int32)])
            codes[name], tables[name] = column[order], table
        return CatalogueBase(
            ids=ids[order],
            offsets=offsets,
            blob=np.frombuffer(b"".join(encoded[i] for i in order.tolist()), np.uint8),
            frame_counts=frame_counts[order],
            frame_times=frame_times[order],
            label_ids=np.concatenate([keyed[k] for k in keys]) if keys else np.zeros(0, np.int64),
            key_rows={k: (int(bounds[i]), int(bounds[i + 1])) for i, k in enumerate(keys)},
            codes=codes,
            tables=tables,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        keys = sorted(self.key_rows)
        bounds = np.array([self.key_rows[k][0] for k in keys] + [self.label_ids.size], np.int64)
        arrays = {
            "ids": self.ids,
            "offsets": self.offsets,
            "blob": self.blob,
            "frame_counts": self.frame_counts,
            "frame_times": self.frame_times,
            "label_ids": self.label_ids,
            "label_bounds": bounds,
            "label_keys": np.frombuffer(orjson.dumps(keys), np.uint8),
        }
        for name in CODED:
            arrays[f"{name}_codes"] = self.codes[name]
            arrays[f"{name}_table"] = np.frombuffer(orjson.dumps(self.tables[name]), np.uint8)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> CatalogueBase:
        keys = orjson.loads(arrays["label_keys"].tobytes())
        bounds = arrays["label_bounds"]
        return cls(
            ids=arrays["ids"],
            offsets=arrays["offsets"],
            blob=arrays["blob"],
            frame_counts=arrays["frame_counts"],
            frame_times=arrays["frame_times"],
            label_ids=arrays["label_ids"],
            key_rows={k: (int(bounds[i]), int(bounds[i + 1])) for i, k in enumerate(keys)},
            codes={name: arrays[f"{name}_codes"] for name in CODED},
            tables={name: orjson.loads(arrays[f"{name}_table"].tobytes()) for name in CODED},
        )

    def rows(self, clip_ids: np.ndarray) -> np.ndarray:
        """The rows of ``clip_ids`` ``(M,)`` (-1: not held)."""
        if not self.ids.size:
            return np.full(clip_ids.size, -1, np.int64)
        at = np.minimum(self.ids.searchsorted(clip_ids), self.ids.size - 1)
        return np.where(self.ids[at] == clip_ids, at, -1)

    def row(self, clip_id: int) -> int:
        """The row of ``clip_id``, or -1."""
        at = int(self.ids.searchsorted(clip_id))
        return at if at < self.ids.size and int(self.ids[at]) == clip_id else -1

    @cached_property
    def _row_table(self) -> tuple[list[int], memoryview] | None:
        """For every run of ``2**ROW_BITS`` ids (``id >> ROW_BITS``), the row of its first
        held id (and one past the last run), with the ids as a view Python indexes directly.
        A library's ids run nearly without gaps (database keys), so a clip's row is then its
        run's first row plus its distance from that row's id, checked with one read — not a
        binary search's ~20 reads scattered over 8 MB of ids at a million clips. ``None``:
        ids too sparse for a small table (the binary search)."""
        if not self.ids.size:
            return None
        runs = (int(self.ids[-1]) >> ROW_BITS) + 2
        if runs > MAX_ROW_BUCKETS:
            return None
        starts = self.ids.searchsorted(np.arange(runs, dtype=np.int64) << ROW_BITS)
        view = _int64_view(self.ids)
        return starts.tolist(), view

    def row_of(self, clip_id: int) -> int:
        """:meth:`row` through the row table (see :attr:`_row_table`)."""
        table = self._row_table
        if table is None:
            return self.row(clip_id)
        starts, ids = table
        run = clip_id >> ROW_BITS
        if not 0 <= run < len(starts) - 1:
            return -1
        first, stop = starts[run], starts[run + 1]
        if first == stop:
            return -1
        guess = first + clip_id - ids[first]
        if first <= guess < stop and ids[guess] == clip_id:
            return guess
        at = bisect_left(ids, clip_id, first, stop)
        return at if at < stop and ids[at] == clip_id else -1

    def heading(self, row: int) -> list[Any]:
        """The stored fields of ``row``'s clip (:func:`encode_entry`'s list, ``name``,
        ``format``, ``filenames``, ``skeleton_family``, ``labels`` first) as decoded, no
        entry built: what a search's hit shows."""
        offsets = self._offsets
        fields: list[Any] = orjson.loads(self.blob.data[offsets[row] : offsets[row + 1]])
        return fields

    @cached_property
    def _offsets(self) -> memoryview:
        return _int64_view(self.offsets)

    def entry(self, row: int) -> ClipEntry:
        start, stop = int(self.offsets[row]), int(self.offsets[row + 1])
        return decode_entry(int(self.ids[row]), self.blob.data[start:stop])

    def entries(self, rows: np.ndarray) -> list[ClipEntry]:
        """The entries of ``rows`` ``(M,)`` (all held): a search's hits, read in one gather
        of their ids and offsets."""
        ids = self.ids[rows].tolist()
        starts = self.offsets[rows].tolist()
        stops = self.offsets[rows + 1].tolist()
        blob = self.blob.data
        return [
            decode_entry(clip_id, blob[start:stop])
            for clip_id, start, stop in zip(ids, starts, stops, strict=True)
        ]

    def with_key(self, key: str) -> np.ndarray:
        start, stop = self.key_rows.get(key, (0, 0))
        return self.label_ids[start:stop]

    def matching(self, name: str, test: Callable[[Any], bool]) -> np.ndarray:
        """Ids of the rows whose coded field ``name`` passes ``test``."""
        table = self.tables[name]
        passing = [code for code, value in enumerate(table) if test(value)]
        if test(None):
            passing.append(-1)
        return self.ids[np.isin(self.codes[name], np.asarray(passing, np.int32))]
