"""What an import run did: every clip found ends imported, a duplicate or failed."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    pass


@dataclass(frozen=True)
class Imported:
    path: Path
    clip_id: int
    skeleton: Path | None  # the .asf an .amc was paired with


@dataclass(frozen=True)
class Duplicate:
    path: Path
    clip_id: int
    clip_name: str
    updated: bool = False  # the import gave the stored clip new labels (or source, licence)


@dataclass(frozen=True)
class Failed:
    """A clip not stored: ``refused`` when its file cannot be stored as it is (a parse error,
    no skeleton, an ``.amc`` without ``.asf``: running again changes nothing), not when the
    run failed it (storage, a crash, a file unreadable or changing meanwhile)."""

    path: Path
    reason: str
    refused: bool = False


@dataclass
class ImportReport:
    """What a run did: every clip found ends in exactly one of the three lists."""

    found: int = 0
    imported: list[Imported] = field(default_factory=list)
    duplicates: list[Duplicate] = field(default_factory=list)
    failed: list[Failed] = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0
    workers: int = 0
    # Refusals an earlier run reported for the same bytes with the same reason (see
    # RefusalMemory): expected, so they do not fail the run unless --strict.
    known_refusals: set[Path] = field(default_factory=set)

    @property
    def new_failures(self) -> list[Failed]:
        """The failures no earlier run reported: every failure but known refusals."""
        return [f for f in self.failed if not (f.refused and f.path in self.known_refusals)]

    @property
    def done(self) -> int:
        return len(self.imported) + len(self.duplicates) + len(self.failed)

    def skeletons(self) -> dict[Path, int]:
        """The ``.asf`` files ASF/AMC clips were imported with, and how many clips each."""
        used: dict[Path, int] = {}
        for clip in self.imported:
            if clip.skeleton is not None:
                used[clip.skeleton] = used.get(clip.skeleton, 0) + 1
        return used
