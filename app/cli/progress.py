"""The progress bar the long commands (``import``, ``reindex``, ``export``) show on stderr."""

from __future__ import annotations

from typing import Any


class ProgressBar:
    """A rich progress bar (clips, clips/s, elapsed, ETA) on stderr, started on the first
    update — after the worker processes are forked, as it runs a thread."""

    def __init__(self, doing: str = "importing") -> None:
        self._doing = doing
        self._progress: Any = None
        self._task: Any = None
        self.total = 0

    def start(self, found: int, workers: int) -> None:
        self.total = found

    def update(self, report: Any) -> None:
        self.set_done(report.done)

    def set_done(self, done: int) -> None:
        if self._progress is None:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
                TimeRemainingColumn,
            )

            self._progress = Progress(
                TextColumn(self._doing),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[rate]}"),
                TimeElapsedColumn(),
                TextColumn("ETA"),
                TimeRemainingColumn(),
                console=Console(stderr=True),
            )
            self._progress.start()
            self._task = self._progress.add_task("import", total=self.total, rate="")
        task = self._progress.tasks[0]
        rate = f"{task.speed:.0f} clips/s" if task.speed else ""
        self._progress.update(self._task, completed=done, rate=rate)

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()
