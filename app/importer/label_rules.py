"""Labels (and source, licence) an import gives each clip: from a TSV, a regex over paths,
the folder names."""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from app.discovery import ClipSource
from app.errors import InvalidInput
from app.labels import (
    choose_label_columns,
    compile_label_regex,
    labels_from_regex,
    labels_from_tsv,
    normalise_labels,
)
from app.services.uploads import normalise_note

if TYPE_CHECKING:
    pass

# TSV columns that say where a clip comes from and how it may be used: not labels.
NOTE_COLUMNS = {"source": "source", "licence": "licence", "license": "licence"}


@dataclass(frozen=True)
class LabelRules:
    """Where the labels of an imported clip come from.

    ``tsv``: clip key (file stem) -> {kind: value}; ``regex``: named groups over the path
    relative to the folder given (``kind`` = group name); ``fixed``: labels every clip gets.
    A clip is stored with the values (kinds are not stored), TSV first, then the regex's
    groups, then ``fixed``; repeated values are kept once.

    The TSV columns named ``source`` and ``licence`` (or ``license``) are not labels: they
    give the clip's source and licence (``notes``). Of the other columns, ``columns`` chooses
    the label columns; by default those not holding free text
    (:func:`app.labels.choose_label_columns`); ``left_out`` names the others.
    """

    tsv: dict[str, dict[str, str]] | None = None
    regex: re.Pattern[str] | None = None
    fixed: tuple[str, ...] = ()
    notes: dict[str, dict[str, str]] = field(default_factory=dict)
    left_out: tuple[str, ...] = ()
    fixed_notes: dict[str, str] = field(default_factory=dict)  # --source, --licence

    @classmethod
    def build(
        cls,
        *,
        tsv: Path | None = None,
        regex: str | None = None,
        fixed: Sequence[str] = (),
        columns: Sequence[str] | None = None,
        source: str | None = None,
        licence: str | None = None,
    ) -> LabelRules:
        """Read the TSV and compile the regex (:class:`InvalidInput` when unusable);
        ``source`` and ``licence`` are every clip's unless its TSV row gives its own."""
        table: dict[str, dict[str, str]] | None = None
        notes: dict[str, dict[str, str]] = {}
        left_out: tuple[str, ...] = ()
        if tsv is not None:
            rows = labels_from_tsv(tsv)
            notes = {
                key: {NOTE_COLUMNS[k]: v for k, v in row.items() if k in NOTE_COLUMNS}
                for key, row in rows.items()
            }
            tags = {
                k: {c: v for c, v in r.items() if c not in NOTE_COLUMNS} for k, r in rows.items()
            }
            table, left_out = choose_label_columns(tags, columns)
        elif columns is not None:
            raise InvalidInput("--label-columns chooses columns of --labels-tsv; give that too")
        return cls(
            tsv=table,
            regex=compile_label_regex(regex) if regex is not None else None,
            fixed=normalise_labels(fixed),
            notes=notes,
            left_out=left_out,
            fixed_notes={
                key: note
                for key, value in (("source", source), ("licence", licence))
                if (note := normalise_note(f"--{key}", value)) is not None
            },
        )

    def notes_of(self, source: ClipSource) -> dict[str, str]:
        """The clip's source and licence: its TSV row's, else the command line's."""
        return {**self.fixed_notes, **self.notes.get(source.name, {})}

    def labels(self, source: ClipSource) -> list[str]:
        kinds: dict[str, str] = {}
        if self.tsv is not None:
            kinds.update(self.tsv.get(source.name, {}))
        if self.regex is not None:
            kinds.update(labels_from_regex(self.regex, source.relative_path))
        return [*kinds.values(), *self.fixed]
