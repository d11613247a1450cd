"""The files earlier runs refused, remembered so a new run can tell a new failure from one
already reported."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from app.discovery import file_digest
from app.importer.report import ImportReport

if TYPE_CHECKING:
    pass

REFUSALS_FILE = "import-refusals.json"


def _file_sha256(path: Path) -> str | None:
    try:
        return file_digest(path)
    except OSError:
        return None


class RefusalMemory:
    """The files earlier runs refused, so a run over the same folders can tell a new failure
    from one already reported: ``<data dir>/import-refusals.json`` maps each refused file's
    absolute path to the sha256 of its bytes and the reason given. A refusal is *known* when
    the same bytes were refused for the same reason before; editing the file, or a release
    that refuses it for another reason, makes it new again."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def _load(self) -> dict[str, dict[str, str]]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
            refused = data["refused"]
        except (OSError, ValueError, KeyError, TypeError):
            return {}  # none yet (or unreadable: every refusal counts as new, once)
        return {
            str(path): entry
            for path, entry in refused.items()
            if isinstance(entry, dict) and {"sha256", "reason"} <= entry.keys()
        }

    def settle(self, report: ImportReport, found: set[Path]) -> None:
        """Mark the report's known refusals, then remember this run's: its refusals replace
        what was remembered of their files, and files it found and did not refuse are
        forgotten (files under other folders are kept)."""
        remembered = self._load()
        seen = {str(path.resolve()) for path in found}
        refusals: dict[str, dict[str, str]] = {}
        for failure in report.failed:
            if not failure.refused:
                continue
            key = str(failure.path.resolve())
            seen.add(key)
            sha = _file_sha256(failure.path)
            if sha is None:
                continue
            entry = {"sha256": sha, "reason": failure.reason}
            if remembered.get(key) == entry:
                report.known_refusals.add(failure.path)
            refusals[key] = entry
        kept = {key: entry for key, entry in remembered.items() if key not in seen}
        if not refusals and kept == remembered:
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            partial = self.path.with_name(self.path.name + ".partial")
            text = json.dumps({"refused": {**kept, **refusals}}, indent=1, sort_keys=True)
            partial.write_text(text, encoding="utf-8")
            partial.replace(self.path)
        except OSError as error:
            print(f"mocap-index: could not remember the refused files: {error}", file=sys.stderr)
