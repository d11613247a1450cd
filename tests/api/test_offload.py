"""Where a search runs (app/api/offload.py): inline once searches of its kind are quick, in a
thread while they are slow, decided by their measured CPU time."""

from __future__ import annotations

import threading
import time

import anyio

from app.api.offload import INLINE_BELOW, Offload


def _burn(seconds: float) -> None:
    """Spend ``seconds`` of this thread's CPU time."""
    until = time.thread_time() + seconds
    while time.thread_time() < until:
        pass


def test_a_kind_whose_first_call_was_slow_comes_back_inline_within_a_few_calls() -> None:
    # A cold index's first search is slow (it builds what later ones reuse); the ones after
    # it are quick and must run on the event loop again soon, not after hundreds of calls
    # handed to a thread (each measured call in a thread costs a clock read: nothing there).
    offload = Offload(anyio.CapacityLimiter(2))
    main = threading.get_ident()
    where: list[bool] = []

    def quick() -> None:
        where.append(threading.get_ident() == main)

    def slow() -> None:
        _burn(20 * INLINE_BELOW)
        quick()

    async def calls() -> None:
        await offload.run("search", slow)
        for _ in range(40):
            await offload.run("search", quick)

    anyio.run(calls)
    assert where[0] is False  # the first of a kind runs in a thread
    # 20x the limit decays under it in ~14 measured calls (a fifth of the gap a call).
    assert where.index(True) <= 20, where
    assert all(where[where.index(True) :]), where
    estimate = offload.estimate("search")
    assert estimate is not None and estimate < INLINE_BELOW


def test_a_slow_kind_stays_in_a_thread() -> None:
    offload = Offload(anyio.CapacityLimiter(2))
    main = threading.get_ident()
    where: list[bool] = []

    def slow() -> None:
        _burn(2 * INLINE_BELOW)
        where.append(threading.get_ident() == main)

    async def calls() -> None:
        for _ in range(6):
            await offload.run("moments", slow)

    anyio.run(calls)
    assert not any(where), where
