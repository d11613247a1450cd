"""The search lane: one thread that scans the index for the plain searches waiting at once,
in one FAISS call, while the event loop goes on with the requests around them.

A plain ``GET /search`` spends most of its search in FAISS at a million clips (the cells'
graph and a dozen lists of 135 numbers a vector: 132 of 195 us in-process for ``motion``,
bench/README.md), and FAISS lets go of the GIL while it scans. Run inline, the scan holds up
the loop; handed to a thread pool one search at a time, the wake-ups and the fight for the
GIL cost as much as it saves (app/api/offload.py). The lane takes the middle way:

* the loop does what is Python — the checks, the query's vector, the hits' headings, the
  body — and hands only the scan to the lane;
* the lane takes every scan waiting when it wakes and makes one FAISS call per index for
  all of them (their answers are each the one the query gets alone,
  :meth:`HeldIndex.nearest_many`), then hands all the answers back to the loop in one
  call: one wake-up and one GIL hand-over per batch, not per search;
* so under load the scans run on another core beside the loop's work, and batches grow
  with the load;
* once a lane runs, the process's switch interval is 0.1 ms (:data:`SWITCH_SECONDS`): the
  lane needs the GIL back after each scan, and a loop busy with requests lets go of it
  only when forced to (5 ms by default, which held the lane to a batch every ~15 ms).

It is used only when other plain searches come while one waits in it
(:meth:`SearchLane.wanted`): a lone search runs inline, as before, since nothing could
overlap with it and the hop would be its latency. With as many busy server processes as
cores it gains little (the scans take a core another process would use).
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import threading
from collections import defaultdict
from typing import Any

import numpy as np

from app.index.held_index import HeldIndex

Answer = list[tuple[int, float]]  # (id, Euclidean distance), nearest first
# One lone search in this many goes to the lane to see whether others come meanwhile (see
# SearchLane.wanted): its hop costs that search ~0.1 ms; the median of lone searches keeps.
PROBE_EVERY = 32
# The interpreter's switch interval once a lane runs (Python's default: 5 ms); see _start.
SWITCH_SECONDS = 0.0001


class SearchLane:
    """One daemon thread scanning indexes for the plain searches handed to it (see the module
    docstring); started at the first search handed to it."""

    def __init__(self) -> None:
        self._waiting: list[tuple[HeldIndex, np.ndarray, int, int, asyncio.Future[Answer]]] = []
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._thread: threading.Thread | None = None
        self._pid = 0  # the process the thread runs in (a forked child has none)
        self._since_probe = 0
        self.in_flight = 0  # plain searches between their start and their answer (the loop's)
        self.scanned = 0  # searches scanned here, and in how many FAISS calls (the lane's own
        self.calls = 0  # count: for tests and a look at how well it batches)

    def wanted(self) -> bool:
        """Whether a new plain search's scan should go to the lane: when another plain search
        is in flight (waiting for the lane: the loop has had other work meanwhile), and for
        one search in :data:`PROBE_EVERY` otherwise. A search run inline holds the loop
        from start to end, so two are never in flight unless one waits in the lane: the
        probe is what finds out that requests are waiting. Under load, those arriving while
        it waits join it, and each batch brings the next; once requests stop overlapping,
        searches go back inline."""
        if self.in_flight > 1:
            return True
        self._since_probe += 1
        if self._since_probe < PROBE_EVERY:
            return False
        self._since_probe = 0
        return True

    async def nearest(self, index: HeldIndex, vector: np.ndarray, k: int, exclude: int) -> Answer:
        """``index.nearest(vector, k, exclude=exclude)``, scanned in the lane."""
        future: asyncio.Future[Answer] = asyncio.get_running_loop().create_future()
        if self._pid != os.getpid() or self._thread is None or not self._thread.is_alive():
            self._start()  # the first search of this process (or a forked one)
        with self._lock:
            self._waiting.append((index, vector, k, exclude, future))
            first = len(self._waiting) == 1
        if first:
            self._wake.set()
        return await future

    def _start(self) -> None:
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._waiting = []
        self._pid = os.getpid()
        # The lane takes the GIL back after each FAISS call and at each wake-up, while the
        # loop, busy with requests, holds it until forced to let go: after Python's 5 ms,
        # which held the lane to a batch every ~15 ms (bench/README.md). Lowered for good:
        # lowering it only while batches kept coming measured slower (the load's first
        # batches waited 5 ms again each time it had paused).
        sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_SECONDS))
        self._thread = threading.Thread(target=self._run, name="search-lane", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self._wake.wait()
            with self._lock:
                batch, self._waiting = self._waiting, []
                self._wake.clear()
            if not batch:
                continue
            try:
                self._scan(batch)
            except BaseException as error:  # never a search left waiting, never a dead lane
                _hand_back([(entry[4], None, error) for entry in batch])

    def _scan(self, batch: list[tuple[HeldIndex, np.ndarray, int, int, Any]]) -> None:
        # One FAISS call per index and k (searches of another descriptor or k wait together
        # but are answered by their own call).
        groups: dict[tuple[int, int], list[int]] = defaultdict(list)
        for at, (index, _, k, _, _) in enumerate(batch):
            groups[(id(index), k)].append(at)
        answers: list[tuple[Any, Answer | None, BaseException | None]] = []
        for members in groups.values():
            index, _, k, _, _ = batch[members[0]]
            futures = [batch[at][4] for at in members]
            try:
                vectors = np.stack([batch[at][1] for at in members])
                found = index.nearest_many(vectors, k, [batch[at][3] for at in members])
                self.scanned += len(members)
                self.calls += 1
            except BaseException as error:  # each waiting search raises it
                answers.extend((future, None, error) for future in futures)
                continue
            answers.extend(
                (future, answer, None) for future, answer in zip(futures, found, strict=True)
            )
        _hand_back(answers)


def _hand_back(answers: list[tuple[Any, Answer | None, BaseException | None]]) -> None:
    """From the lane: the answers (or errors) to their searches' loops, one call a loop."""
    by_loop: dict[Any, list[tuple[Any, Answer | None, BaseException | None]]] = defaultdict(list)
    for answer in answers:
        by_loop[answer[0].get_loop()].append(answer)
    for loop, delivered in by_loop.items():
        # RuntimeError: the loop is closed (the server stopping), nobody waits
        with contextlib.suppress(RuntimeError):
            loop.call_soon_threadsafe(_deliver, delivered)


def _deliver(answers: list[tuple[Any, Answer | None, BaseException | None]]) -> None:
    """On the loop: every answer of a batch to its search (unless it was cancelled)."""
    for future, answer, error in answers:
        if future.done():
            continue
        if error is not None:
            future.set_exception(error)
        else:
            future.set_result(answer)
