"""Where a search runs: on the event loop when searches like it have been quick, in a worker
thread when they have been slow — decided by their measured time, not by a guess.

Handing work to a thread costs a wake-up, a context switch and a fight for the GIL: at a
million clips that was half of the CPU of a 0.2-ms search and halved the throughput. Running
on the event loop costs the other connections their wait while it runs: a 30-ms search there
put a p99 of 2 s on the rest. So each kind of search (the caller names it: descriptor, label
filter or not, ...) keeps the moving average of the CPU time it took; while that is under
:data:`INLINE_BELOW` it runs right on the loop, else in a thread. The first of a kind runs in
a thread, until there is a measure. (CPU time: what a search costs the others; its wall time
also counts every other process of a busy machine. A search waiting on the database — with
``MOCAP_INDEX_REFRESH_SECONDS=0`` it polls the feed first — is measured by its CPU too.)
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import TypeVar

import anyio

T = TypeVar("T")

# Longest a search may hold the event loop: shorter than a request's round trip through the
# loop under load, so a quick search never waits behind another one for long.
INLINE_BELOW = 0.002
WEIGHT = 0.2  # of the newest measure in the moving average
# Calls measured: the first few of a kind, every one that runs in a thread, and one in
# SAMPLE_EVERY of those that run inline. Reading a thread's CPU clock is a system call (no
# vDSO), which on this VM cost more than an inline search it measured; next to a thread hop
# it is nothing, and a kind whose first calls were slow (a cold index's first search: ~90
# ms at a million clips) must come back inline within a few calls, not a few hundred.
FIRST_MEASURED = 4
SAMPLE_EVERY = 32


class Offload:
    """Runs blocking calls inline or in a thread of ``limiter`` (see the module docstring)."""

    def __init__(self, limiter: anyio.CapacityLimiter, inline_below: float = INLINE_BELOW):
        self._limiter = limiter
        self._inline_below = inline_below
        self._seconds: dict[Hashable, float] = {}
        self._calls: dict[Hashable, int] = {}

    def estimate(self, kind: Hashable) -> float | None:
        """The moving average of the CPU seconds a call of ``kind`` took (None: never
        measured)."""
        return self._seconds.get(kind)

    def quick(self, kind: Hashable) -> bool:
        """Whether calls of ``kind`` have been quick enough to run on the loop."""
        estimate = self._seconds.get(kind)
        return estimate is not None and estimate < self._inline_below

    def _measured(self, kind: Hashable, seconds: float) -> None:
        before = self._seconds.get(kind)
        self._seconds[kind] = seconds if before is None else before + WEIGHT * (seconds - before)

    def _timed(self, kind: Hashable, call: Callable[[], T]) -> T:
        calls = self._calls.get(kind, 0)
        self._calls[kind] = calls + 1
        if self.quick(kind) and calls >= FIRST_MEASURED and calls % SAMPLE_EVERY:
            return call()
        # CPU time of this thread, not wall time: on a loaded machine (or behind the GIL in
        # a thread) a 0.3-ms search can take 3 ms of wall time, and would never run inline.
        started = time.thread_time()
        try:
            return call()
        finally:
            self._measured(kind, time.thread_time() - started)

    async def run(self, kind: Hashable, call: Callable[[], T]) -> T:
        """``call()``: inline when calls of ``kind`` have been quick, else in a thread."""
        if self.quick(kind):
            return self._timed(kind, call)
        return await anyio.to_thread.run_sync(self._timed, kind, call, limiter=self._limiter)
