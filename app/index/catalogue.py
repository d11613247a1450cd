"""The catalogue: what a search shows of each clip, held in memory beside the indexes.

A search answers with its hits' names, formats, file names, skeleton families and labels,
the query clip's stored fields, and (moments) the clips' frame rates and lengths. Read from
the database that was four statements per search, a quarter of a request at a million clips.
The catalogue holds the same facts for every clip (a :class:`ClipEntry` each: a clip's row
without its joint mapping and the files' hashes), and which clips carry each label, so label
filters need no SQL either.

Like the indexes it is a cache of the database, the source of truth: written to
``<index dir>/catalogue.arrays`` (:mod:`app.index.array_file`) with the change-feed position
it reflects, loaded at start and brought up to date with the clips changed since (inserted,
deleted, renamed, relabelled: migration 0009 puts updates on the feed), rebuilt from the
database when the file is missing, damaged or disagrees with it, and kept current by the same
feed as the indexes (:meth:`app.services.library.Library.sync_indexes`).

Layout: a *base* (:class:`app.index.catalogue_base.CatalogueBase`) — the file's arrays,
memory-mapped, so every server process of one machine shares one copy — and an *overlay* of
the clips changed since, per process. Each clip of the base is one orjson-encoded list
(decoded when a search shows it, ~2 us); frame counts and frame times are columns too, and
each label key lists its clips. When the overlay grows past
``max(COMPACT_MIN, base / COMPACT_SHARE)`` entries, base and overlay are merged into a new
base and saved.

Readers take no lock: a change builds a new :class:`_State` and swaps it in one assignment.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from app.db.entries import ClipEntry
from app.index.array_file import read_arrays, verify_arrays, write_arrays
from app.index.catalogue_base import CODED, CatalogueBase
from app.index.delayed_save import DelayedSave
from app.labels import label_filter, label_key

log = logging.getLogger(__name__)

STEM = "catalogue"
FORMAT = 2  # the layout of the file; another one is rebuilt from the database
COMPACT_MIN = 20_000  # overlay entries that make a new base (at least)
COMPACT_SHARE = 20  # ... or this share of the base (1/20)


class ClipSource(Protocol):
    """The database's view of the clips (one consistent snapshot)."""

    def watermark(self) -> int:
        """The feed position of this snapshot."""
        ...

    def count(self) -> int:
        """How many clips the database holds."""
        ...

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 sorted ids of every clip."""
        ...

    def entries(self) -> Iterator[ClipEntry]:
        """Every clip, in id order."""
        ...

    def changed(self, since: int) -> np.ndarray:
        """``(N,)`` int64 ids of the clips changed at or after feed position ``since``."""
        ...

    def entries_of(self, ids: np.ndarray) -> dict[int, ClipEntry]:
        """The clips among ``ids`` that exist, by id."""
        ...


@dataclass(frozen=True)
class _State:
    """The base and the overlay (clip id -> its entry now, ``None`` when deleted), with the
    overlay's clips by label key, the base ids the overlay hides (sorted) and the count."""

    base: CatalogueBase
    overlay: dict[int, ClipEntry | None] = field(default_factory=dict)
    overlay_keys: dict[str, frozenset[int]] = field(default_factory=dict)
    hidden: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    size: int = -1

    def __post_init__(self) -> None:
        if self.size < 0:
            object.__setattr__(self, "size", int(self.base.ids.size))


class Catalogue(DelayedSave):
    """The display data of every clip (see the module docstring), persisted in ``directory``.

    ``autosave_below``, ``save_delay``: a catalogue of at most that many clips is saved that
    many seconds after a change (changes meanwhile batched); a larger one when it compacts
    and when the library closes.
    """

    def __init__(
        self, directory: Path, *, autosave_below: int = 20_000, save_delay: float = 1.0
    ) -> None:
        self.directory = directory
        self.autosave_below = autosave_below
        self.save_delay = save_delay
        self.autosave = True  # False: changes are saved only by an explicit save() or flush()
        self._unchecked: tuple[dict[str, np.ndarray], dict[str, Any]] | None = None
        self._state = _State(CatalogueBase.empty())
        self._init_saving()
        self._changing = threading.Lock()
        self._save_lock = threading.Lock()

    # -- reads -----------------------------------------------------------------------------

    def __len__(self) -> int:
        return self._state.size

    def get(self, clip_id: int) -> ClipEntry | None:
        state = self._state
        if clip_id in state.overlay:
            return state.overlay[clip_id]
        row = state.base.row_of(clip_id)
        return None if row < 0 else state.base.entry(row)

    def get_many(self, clip_ids: Iterable[int]) -> dict[int, ClipEntry]:
        """The clips among ``clip_ids`` that exist, by id (one binary search for all)."""
        state = self._state
        found: dict[int, ClipEntry] = {}
        overlay = state.overlay
        if overlay:
            wanted = []
            for clip_id in clip_ids:
                if clip_id in overlay:
                    entry = overlay[clip_id]
                    if entry is not None:
                        found[clip_id] = entry
                else:
                    wanted.append(clip_id)
        else:  # no change since the base was written: every id is looked up in it
            wanted = list(clip_ids)
        if wanted:
            base = state.base
            rows = base.rows(np.asarray(wanted, np.int64))
            held = rows[rows >= 0]
            for entry in base.entries(held):
                found[entry.id] = entry
        return found

    def headings(self, clip_ids: Iterable[int]) -> dict[int, Sequence[Any]]:
        """What a search's hit shows of the clips among ``clip_ids`` that exist, by id: a
        sequence of the entry's fields after the id, ``name``, ``format``, ``filenames``,
        ``skeleton_family``, ``labels`` first (:class:`ClipEntry` order) — decoded without
        building the entry (a plain search shows a dozen; :meth:`get_many` builds them)."""
        state = self._state
        overlay = state.overlay
        base = state.base
        found: dict[int, Sequence[Any]] = {}
        for clip_id in clip_ids:
            if clip_id in overlay:
                entry = overlay[clip_id]
                if entry is not None:
                    found[clip_id] = entry[1:]
                continue
            row = base.row_of(clip_id)
            if row >= 0:
                found[clip_id] = base.heading(row)
        return found

    def frames(self, clip_ids: Iterable[int]) -> dict[int, tuple[float, int]]:
        """``(frame_time, frame_count)`` of the clips among ``clip_ids`` that exist, by id,
        read from the columns (no entry decoded: a moments search asks for dozens)."""
        state = self._state
        found: dict[int, tuple[float, int]] = {}
        wanted = []
        for clip_id in clip_ids:
            if clip_id in state.overlay:
                entry = state.overlay[clip_id]
                if entry is not None:
                    found[clip_id] = (entry.frame_time, entry.frame_count)
            else:
                wanted.append(clip_id)
        if wanted:
            base = state.base
            rows = base.rows(np.asarray(wanted, np.int64))
            held = rows >= 0
            times = base.frame_times[rows[held]].tolist()
            counts = base.frame_counts[rows[held]].tolist()
            kept = np.asarray(wanted, np.int64)[held].tolist()
            found.update(zip(kept, zip(times, counts, strict=True), strict=True))
        return found

    def frame_arrays(self, clip_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`frames` as arrays: which of ``clip_ids`` ``(M,)`` exist ``(M,)`` bool, and
        their ``(K, 2)`` float64 rows of (frame_time, frame_count), in the order of
        ``clip_ids``. Without an overlay, no Python object a clip (a moments search asks
        for hundreds of clips a round)."""
        state = self._state
        ids = np.asarray(clip_ids, np.int64)
        if state.overlay:
            listed = self.frames(ids.tolist())
            held = np.array([i in listed for i in ids.tolist()], bool)
            rows = [listed[i] for i in ids[held].tolist()]
            return held, np.array(rows, np.float64).reshape(-1, 2)
        base = state.base
        at = base.rows(ids)
        held = at >= 0
        kept = at[held]
        facts = np.empty((kept.size, 2))
        facts[:, 0] = base.frame_times[kept]
        facts[:, 1] = base.frame_counts[kept]
        return held, facts

    def ids(self) -> np.ndarray:
        """``(N,)`` int64 sorted ids of every clip."""
        state = self._state
        return _combine(
            state.base.ids, state, [i for i, e in state.overlay.items() if e is not None]
        )

    def ids_with_labels(self, labels: str | Sequence[str] | None) -> np.ndarray:
        """``(N,)`` int64 sorted ids of the clips carrying every label of ``labels`` (any
        case); every clip for an empty filter."""
        keys = list(dict.fromkeys(label_key(label) for label in label_filter(labels)))
        if not keys:
            return self.ids()
        state = self._state
        found: np.ndarray | None = None
        for key in sorted(keys, key=lambda k: len(state.base.with_key(k))):
            ids = _combine(state.base.with_key(key), state, state.overlay_keys.get(key, ()))
            found = ids if found is None else np.intersect1d(found, ids, assume_unique=True)
            if not found.size:
                break
        assert found is not None
        return found

    def ids_matching(self, name: str, test: Callable[[Any], bool]) -> np.ndarray:
        """``(N,)`` int64 sorted ids of the clips whose ``name`` (``source`` or ``licence``,
        kept as coded columns) passes ``test`` (called once per distinct value, and once
        with ``None`` for the clips without one)."""
        if name not in CODED:
            raise ValueError(f"not a coded field: {name!r}; choose one of {', '.join(CODED)}")
        state = self._state
        overlay = [i for i, e in state.overlay.items() if e is not None and test(getattr(e, name))]
        return _combine(state.base.matching(name, test), state, overlay)

    def entries(self) -> Iterator[ClipEntry]:
        """Every clip, in id order."""
        state = self._state
        for clip_id in self.ids().tolist():
            entry = state.overlay.get(clip_id)
            yield entry if entry is not None else state.base.entry(state.base.row(clip_id))

    # -- changes ---------------------------------------------------------------------------

    def apply_changes(
        self,
        changed: np.ndarray,
        entries: Mapping[int, ClipEntry],
        *,
        synced_to: int | None = None,
        persist: bool | None = None,
    ) -> None:
        """The clips ``changed`` ``(C,)`` changed in the database: those in ``entries`` are
        now as given, the others are gone. Applying the same changes twice changes nothing.
        ``persist``: save now (True), not now (False), or when the catalogue is small."""
        clip_ids = np.unique(np.asarray(changed, np.int64)).tolist()
        with self._changing:
            state = self._state
            overlay = dict(state.overlay)
            keyed = {k: set(v) for k, v in state.overlay_keys.items()}
            size = state.size
            in_base = [i for i in clip_ids if state.base.row(i) >= 0]
            based = set(in_base)
            for clip_id in clip_ids:
                was = overlay.get(clip_id)
                existed = was is not None if clip_id in overlay else clip_id in based
                for key in was.label_keys() if was is not None else ():
                    keyed[key].discard(clip_id)
                new = entries.get(clip_id)
                size += (new is not None) - existed
                if new is None and clip_id not in based:
                    overlay.pop(clip_id, None)  # never in the base: nothing to hide
                else:
                    overlay[clip_id] = new
                for key in new.label_keys() if new is not None else ():
                    keyed.setdefault(key, set()).add(clip_id)
            # Base rows the overlay holds stay hidden until the next compaction.
            hidden = np.union1d(state.hidden, np.asarray(in_base, np.int64))
            self._state = _State(
                state.base, overlay, {k: frozenset(v) for k, v in keyed.items() if v}, hidden, size
            )
            if synced_to is not None:
                self._synced_to = max(self._synced_to, int(synced_to))
            self._unsaved += len(clip_ids)
            compact = len(overlay) > max(COMPACT_MIN, state.base.ids.size // COMPACT_SHARE)
        if compact:
            self.compact()
        if persist:
            self.try_save()
        elif persist is None and clip_ids and not compact:
            self._autosave()

    def replace_all(
        self, entries: Iterable[ClipEntry], *, synced_to: int, persist: bool = True
    ) -> None:
        """Hold exactly ``entries`` (as the database has them at feed position
        ``synced_to``)."""
        base = CatalogueBase.build(entries)
        self._unchecked = None  # that file is no longer used
        with self._changing:
            self._state = _State(base)
            self._synced_to = int(synced_to)
            self._unsaved = int(base.ids.size) + 1
        if persist:
            self.try_save()

    def compact(self) -> None:
        """Merge the overlay into a new base and save it (then map the saved file)."""
        with self._changing:
            state = self._state
            if state.overlay:
                self._state = _State(state.base.merged(state.overlay))
        self.try_save()

    # -- files -----------------------------------------------------------------------------

    def save(self) -> None:
        """Write the base merged with the overlay (atomically, see app.index.array_file),
        then hold the mapped file instead of the copy in memory."""
        with self._save_lock:
            with self._changing:
                state = self._state
                synced_to = self._synced_to
                unsaved = self._unsaved
            base = state.base.merged(state.overlay) if state.overlay else state.base
            write_arrays(
                self.directory,
                STEM,
                base.arrays(),
                {"format": FORMAT, "count": int(base.ids.size), "feed_position": synced_to},
            )
            found = self.read_file()
            with self._changing:
                if self._state is state and not isinstance(found, str):
                    self._state = _State(CatalogueBase.from_arrays(found[0]))
                self._unsaved = max(0, self._unsaved - unsaved)

    def try_save(self) -> bool:
        """:meth:`save`, logging instead of raising when the file cannot be written (the
        catalogue in memory is right; a file that is behind catches up when next loaded)."""
        try:
            self.save()
        except OSError as exc:
            log.warning(
                "could not save the catalogue (%s); it catches up from the database when next "
                "loaded",
                exc,
            )
            return False
        return True

    def _autosave(self) -> None:
        if not self.autosave or len(self) > self.autosave_below:
            return
        if self.save_delay <= 0:
            self.try_save()
            return
        self._schedule_save(self.save_delay)

    def read_file(
        self, *, verify: bool = True
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]] | str:
        """The persisted arrays and metadata, or why they cannot be used (file work only:
        it can run in a thread beside the indexes' reads). ``verify=False``: the checksum is
        checked later, by :meth:`verify_file`."""
        found = read_arrays(self.directory, STEM, {"format": FORMAT}, verify=verify)
        if not verify and not isinstance(found, str):
            self._unchecked = found
        return found

    def verify_file(self) -> str | None:
        """Check the checksum of the file read with ``read_file(verify=False)``: why it
        cannot be used (the caller rebuilds the catalogue), or None."""
        unchecked, self._unchecked = self._unchecked, None
        return None if unchecked is None else verify_arrays(*unchecked)

    def load_or_rebuild(
        self,
        source: ClipSource,
        found: tuple[dict[str, np.ndarray], dict[str, Any]] | str | None = None,
    ) -> str | None:
        """Load the file and bring it up to date with ``source`` (the database): apply the
        clips changed since the file's feed position, then check the count. Rebuild from
        ``source`` when the file cannot be used or the count disagrees. Returns why it was
        rebuilt, or ``None``. ``found``: what :meth:`read_file` returned, if called already."""
        if found is None:
            found = self.read_file()
        watermark = source.watermark()
        problem = found if isinstance(found, str) else None
        if not isinstance(found, str):
            arrays, meta = found
            position = meta.get("feed_position")
            if not isinstance(position, int) or not 0 <= position <= watermark:
                problem = "catalogue was saved from another database"
            else:
                with self._changing:
                    self._state = _State(CatalogueBase.from_arrays(arrays))
                    self._synced_to = position
                    self._unsaved = 0
                touched = source.changed(since=position)
                if touched.size:
                    self.apply_changes(touched, source.entries_of(touched), persist=False)
                self._synced_to = watermark
                expected = source.count()
                if len(self) != expected:
                    problem = f"catalogue holds {len(self)} clips, database {expected}"
                elif position != watermark:
                    self.try_save()
        if problem is None:
            return None
        self.replace_all(source.entries(), synced_to=watermark)
        # An empty one (a new library) is no news: the library says once that it is new.
        level = logging.WARNING if len(self) else logging.DEBUG
        log.log(level, "rebuilt the catalogue from the database (%d clips): %s", len(self), problem)
        return problem


def _combine(base_ids: np.ndarray, state: _State, overlay_ids: Iterable[int]) -> np.ndarray:
    """``base_ids`` (sorted, of the base) without those the overlay hides, with
    ``overlay_ids``: sorted, unique."""
    ids = base_ids
    if state.hidden.size and ids.size:
        ids = ids[~np.isin(ids, state.hidden)]
    extra = np.fromiter(overlay_ids, np.int64)
    return np.union1d(ids, extra) if extra.size else np.asarray(ids, np.int64)
