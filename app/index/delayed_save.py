"""What the caches that follow the change feed and save to a file share (a clip index,
:class:`~app.index.saved_index.SavedIndex`, and the :class:`~app.index.catalogue.Catalogue`):
the feed position they reflect, how many changes are not saved yet, and a save batched a
while after a change (a file per upload would cost more than describing the upload)."""

from __future__ import annotations

import threading


class DelayedSave:
    """Mixin: the constructor calls :meth:`_init_saving`; the class defines :meth:`try_save`."""

    def _init_saving(self) -> None:
        self._synced_to = 0
        self._unsaved = 0
        self._timer: threading.Timer | None = None
        self._timer_lock = threading.Lock()

    @property
    def synced_to(self) -> int:
        """The change-feed position the cache reflects."""
        return self._synced_to

    @property
    def unsaved_changes(self) -> int:
        return self._unsaved

    def mark_synced(self, position: int) -> None:
        """Nothing changed up to feed position ``position``: the cache reflects it."""
        self._synced_to = max(self._synced_to, int(position))

    def try_save(self) -> bool:
        """Save, logging instead of raising when the file cannot be written; whether it was."""
        raise NotImplementedError

    def flush(self) -> None:
        """Save now if anything is unsaved (a pending delayed save is done now instead)."""
        with self._timer_lock:
            timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()
        if self._unsaved:
            self.try_save()

    def _schedule_save(self, delay: float) -> None:
        """Save in ``delay`` seconds, once for every change made meanwhile."""
        with self._timer_lock:
            if self._timer is not None:
                return
            self._timer = threading.Timer(delay, self._timed_save)
            self._timer.daemon = True
            self._timer.start()

    def _timed_save(self) -> None:
        with self._timer_lock:
            self._timer = None
        self.try_save()
