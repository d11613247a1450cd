"""The moments search's in-memory window places against a plain dict of the same rows."""

from __future__ import annotations

import numpy as np
import pytest

from app.index.places import Places, WindowPlaces

BITS = 20


def windows_of(clip_id: int, count: int, rng: np.random.Generator) -> dict[int, tuple[int, int]]:
    """``count`` windows of one clip: id -> (start, stop), starts rising with the ordinal."""
    starts = np.cumsum(rng.integers(1, 20, count))
    return {
        clip_id << BITS | ordinal: (int(start), int(start) + 30)
        for ordinal, start in enumerate(starts)
    }


def places_of(rows: dict[int, tuple[int, int]]) -> Places:
    ids = list(rows)
    return Places.of(
        np.array(ids, np.int64),
        np.array([rows[i][0] for i in ids], np.int64),
        np.array([rows[i][1] for i in ids], np.int64),
    )


def check(places: WindowPlaces, model: dict[int, tuple[int, int]], clips: list[int]) -> None:
    assert len(places) == len(model)
    ids = np.array(sorted(model), np.int64)
    held, starts, stops = places.find(ids)
    assert held.all()
    assert [(s, e) for s, e in zip(starts.tolist(), stops.tolist(), strict=True)] == [
        model[i] for i in ids.tolist()
    ]
    absent = places.find(np.array([7 << BITS | 999, -1, 1 << 62], np.int64))[0]
    assert not absent.any()
    found, offsets = places.of_clips(np.array(clips, np.int64))
    for number, clip_id in enumerate(clips):
        rows = slice(int(offsets[number]), int(offsets[number + 1]))
        expected = sorted(i for i in model if i >> BITS == clip_id)
        assert found.ids[rows].tolist() == expected
        assert found.starts[rows].tolist() == [model[i][0] for i in expected]
        assert np.all(np.diff(found.starts[rows]) > 0)  # in start order


@pytest.mark.parametrize("seed", range(5))
def test_places_follow_random_changes_like_a_dict(seed: int) -> None:
    rng = np.random.default_rng(seed)
    model: dict[int, tuple[int, int]] = {}
    for clip_id in range(1, 30):
        model.update(windows_of(clip_id, int(rng.integers(1, 12)), rng))
    places = WindowPlaces(BITS)
    assert not places.loaded
    places.replace_all(places_of(model))
    assert places.loaded
    check(places, model, list(range(0, 32)))
    for _ in range(40):
        changed = sorted({int(c) for c in rng.integers(1, 40, int(rng.integers(1, 4)))})
        new: dict[int, tuple[int, int]] = {}
        for clip_id in changed:
            model = {i: span for i, span in model.items() if i >> BITS != clip_id}
            if rng.random() < 0.7:  # rewritten (or added); else deleted
                new.update(windows_of(clip_id, int(rng.integers(1, 12)), rng))
        model.update(new)
        places.apply_changes(np.array(changed), places_of(new))
        check(places, model, [*changed, 0, 41])
    gone = sorted({i >> BITS for i in model})[:3]
    places.remove_clips(np.array(gone))
    model = {i: span for i, span in model.items() if i >> BITS not in gone}
    check(places, model, gone)
    assert places.ids_of_clips(np.array(gone)).size == 0


def test_empty_places_answer_nothing() -> None:
    places = WindowPlaces(BITS)
    held, starts, _ = places.find(np.array([1, 2], np.int64))
    assert not held.any() and starts.tolist() == [0, 0]
    found, offsets = places.of_clips(np.array([1, 2], np.int64))
    assert len(found) == 0 and offsets.tolist() == [0, 0, 0]
    places.apply_changes(np.zeros(0, np.int64), Places.empty())
    assert len(places) == 0


def test_changes_from_two_threads_lose_nothing() -> None:
    """A delete (the request's thread) and a sync (another thread) change the places at
    once: each change must see the other's."""
    import threading

    rng = np.random.default_rng(7)
    places = WindowPlaces(BITS)
    places.replace_all(Places.empty())
    per_thread = {name: list(range(start, start + 200)) for name, start in (("a", 1), ("b", 1001))}
    rows = {clip: windows_of(clip, 3, rng) for clips in per_thread.values() for clip in clips}

    def add(clips: list[int]) -> None:
        for clip in clips:
            places.apply_changes(np.array([clip]), places_of(rows[clip]))

    threads = [threading.Thread(target=add, args=(clips,)) for clips in per_thread.values()]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    model = {i: span for windows in rows.values() for i, span in windows.items()}
    check(places, model, [1, 200, 1001, 1200])


def test_windows_of_clips_are_found_by_binary_search_in_the_index(tmp_path) -> None:
    """library.windows_of_clips: the window ids an index holds of some clips, as scanning
    every id held would find them."""
    from app.index.descriptor_index import DescriptorIndex
    from app.index.kinds import IndexOptions
    from app.index.sources import windows_of_clips

    rng = np.random.default_rng(5)
    rows = {clip: windows_of(clip, int(rng.integers(1, 9)), rng) for clip in range(1, 60)}
    ids = np.array(sorted(i for windows in rows.values() for i in windows), np.int64)
    index = DescriptorIndex("w", 4, 1, tmp_path, options=IndexOptions(kind="flat"))
    index.replace_all(ids, rng.random((ids.size, 4)).astype(np.float32), persist=False)
    index.remove(ids[::7], persist=False)
    for clips in ([3], [1, 59, 30], [0, 61], list(range(1, 60))):
        held = index.ids()
        expected = np.sort(held[np.isin(held >> BITS, clips)])
        np.testing.assert_array_equal(np.sort(windows_of_clips(index, np.array(clips))), expected)
