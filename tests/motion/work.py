"""What a reader is made to do, for tests that pin work without timing it: the tokens the
number pattern is given, and how often the reader looks at the clock."""

from __future__ import annotations

import re


class RecordingPattern:
    """Stands in for the number pattern and records the length of every token it is given."""

    def __init__(self, pattern: re.Pattern[str]) -> None:
        self.pattern = pattern
        self.lengths: list[int] = []

    def fullmatch(self, text: str, *args: int) -> re.Match[str] | None:
        self.lengths.append(len(text))
        return self.pattern.fullmatch(text, *args)


class Clock:
    """A fake ``time.monotonic``: each look moves it on by one second."""

    def __init__(self) -> None:
        self.looks = 0

    def __call__(self) -> float:
        self.looks += 1
        return float(self.looks)
