"""The indexes of every descriptor (or of every windowed descriptor and length), by name:
one batch added to all, ids removed from all, all saved."""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import numpy as np

from app.index.descriptor_index import DescriptorIndex


class IndexSet(Mapping[str, DescriptorIndex]):
    """The indexes of every descriptor, by descriptor name."""

    def __init__(self, indexes: Mapping[str, DescriptorIndex]) -> None:
        self._indexes = dict(indexes)

    def __getitem__(self, name: str) -> DescriptorIndex:
        return self._indexes[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._indexes)

    def __len__(self) -> int:
        return len(self._indexes)

    def add(self, ids: np.ndarray | list[int], vectors: Mapping[str, np.ndarray]) -> None:
        """Add one batch: ``vectors[name]`` is ``(N, D_name)`` for the ``(N,)`` ``ids``."""
        for name, array in vectors.items():
            self._indexes[name].add(ids, array)

    def remove(self, ids: np.ndarray | list[int]) -> None:
        """Remove ``ids`` from every index."""
        for index in self._indexes.values():
            index.remove(ids)

    def sizes(self) -> dict[str, int]:
        return {name: index.size for name, index in self._indexes.items()}

    def save(self, *, only_changed: bool = True) -> None:
        """Save every index (with ``only_changed``: those with unsaved changes); a file that
        cannot be written is logged, not raised (see :meth:`DescriptorIndex.try_save`)."""
        for index in self._indexes.values():
            if only_changed:
                index.flush()
            else:
                index.try_save()
