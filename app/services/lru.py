"""A small thread-safe least-recently-used cache (skeleton previews, map layouts)."""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class LRUCache(Generic[K, V]):
    """A small thread-safe least-recently-used cache of at most ``size`` items and, with
    ``weigh``, at most ``max_weight`` in all (e.g. bytes: one hour-long take must not keep
    seven others in memory). The newest item is kept even when it alone weighs more."""

    def __init__(
        self,
        size: int,
        *,
        max_weight: float | None = None,
        weigh: Callable[[V], float] | None = None,
    ) -> None:
        self.size = size
        self.max_weight = max_weight
        self._weigh = weigh
        self._weight = 0.0
        self._items: OrderedDict[K, tuple[V, float]] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: K) -> V | None:
        with self._lock:
            if key not in self._items:
                return None
            self._items.move_to_end(key)
            return self._items[key][0]

    def put(self, key: K, value: V) -> None:
        weight = float(self._weigh(value)) if self._weigh is not None else 0.0
        with self._lock:
            if key in self._items:
                self._weight -= self._items.pop(key)[1]
            self._items[key] = (value, weight)
            self._weight += weight
            while len(self._items) > 1 and (
                len(self._items) > self.size
                or (self.max_weight is not None and self._weight > self.max_weight)
            ):
                self._weight -= self._items.popitem(last=False)[1][1]

    def get_or_compute(self, key: K, compute: Callable[[], V]) -> V:
        found = self.get(key)
        if found is None:
            found = compute()
            self.put(key, found)
        return found

    @property
    def weight(self) -> float:
        return self._weight

    def __len__(self) -> int:
        return len(self._items)
