"""Where the labels of a clip come from: a TSV table keyed by clip, or a regex over its path.

* :func:`labels_from_tsv` reads a tab-separated table whose first row is a header: the first
  column holds the clip key (the file stem, e.g. ``02_01``), every other column is a *label
  kind* (e.g. ``coarse``, ``fine``). An empty cell means "no value of that kind".
* :func:`labels_from_regex` applies a regular expression with named groups to a clip's
  relative path (``re.search``, so it may match anywhere); each named group that matched is a
  label kind. E.g. ``dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\\d+`` gives the Bandai
  ``content`` and ``style``.

Both raise :class:`~app.errors.InvalidInput` with a message a user can act on.

The rules for labels themselves live here too, used by every route, the CLI and the importer:

* :func:`normalise_labels` — what a clip stores: each value split on commas, trimmed, empty ones
  dropped, compared case-insensitively (the first spelling seen is kept, later ones in another
  case are the same label);
* :func:`label_filter` — what a ``label`` filter means: the same splitting, and a clip must
  carry *all* the labels given (in any case); nothing given (or only empty values) = no filter;
* :func:`label_key` — the case-folded form labels are compared (and indexed) by.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import lru_cache
from pathlib import Path

from app.errors import InvalidInput
from app.text import checked_text

MAX_LABEL_LENGTH = 100
MAX_LABELS = 100


def label_key(label: str) -> str:
    """The form labels are compared by: ``"Walk"``, ``"WALK"`` and ``"walk"`` are one label."""
    return label.strip().casefold()


def _split(values: str | Iterable[str] | None, field: str) -> dict[str, str]:
    """key -> first spelling, for each trimmed, non-empty comma-separated value."""
    if values is None:
        return {}
    if isinstance(values, str):
        values = [values]
    found: dict[str, str] = {}
    for value in values:
        for label in checked_text(field, value).split(","):
            label = label.strip()
            if label:
                found.setdefault(label_key(label), label)
    return found


def normalise_labels(values: str | Iterable[str] | None) -> tuple[str, ...]:
    """Labels to store, from repeated fields and/or comma-separated values: trimmed, empty
    ones dropped, case-insensitive duplicates removed (the first spelling kept).

    Raises
    ------
    InvalidInput
        A label over :data:`MAX_LABEL_LENGTH` characters, or over :data:`MAX_LABELS` labels,
        or holding a NUL character (PostgreSQL stores none).
    """
    labels = tuple(_split(values, "labels").values())
    for label in labels:
        if len(label) > MAX_LABEL_LENGTH:
            raise InvalidInput(f"labels: {label[:20]!r}... is over {MAX_LABEL_LENGTH} characters")
    if len(labels) > MAX_LABELS:
        raise InvalidInput(f"labels: at most {MAX_LABELS} labels per clip")
    return labels


def label_filter(values: str | Iterable[str] | None) -> tuple[str, ...]:
    """The labels a ``label`` filter asks for, each clip must carry all of them (compared by
    :func:`label_key`); ``()`` means no filter. ``"walk,happy"``, ``["walk", "happy"]`` and
    ``["walk,", " Happy"]`` all ask for the same two labels; ``""`` and ``[""]`` for none."""
    return tuple(_split(values, "label").values())


def refuse_nul(field: str, values: Iterable[str]) -> None:
    """:class:`InvalidInput` naming ``field`` when a filter's text holds a NUL character or a
    lone surrogate (:func:`~app.text.checked_text`), which no stored text holds."""
    for value in values:
        checked_text(field, value)


def merge_labels(stored: Iterable[str], added: Iterable[str]) -> tuple[str, ...]:
    """``stored`` followed by those of ``added`` it does not already carry (in any case)."""
    merged = _split(list(stored), "labels")
    for key, label in _split(list(added), "labels").items():
        merged.setdefault(key, label)
    return tuple(merged.values())


def labels_from_tsv(path: Path) -> dict[str, dict[str, str]]:
    """Clip key -> {label kind -> value} from a TSV file with a header row.

    The header row's cells name the columns (the first is the key column, whatever its
    name). A file whose first row does not look like a header is refused: a header cell that
    is empty or repeated, a key-column name starting with a digit (as clip keys such as
    ``01_01`` do), or a header whose label-kind cells all reappear as values in their own
    columns (a data row).

    Raises
    ------
    InvalidInput
        Unreadable file, no header, fewer than two columns, a row with more cells than the
        header, or a clip key listed twice.
    """
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except OSError as error:
        raise InvalidInput(f"cannot read the labels file {path}: {error.strerror}") from None
    except UnicodeDecodeError:
        raise InvalidInput(f"the labels file {path} is not UTF-8 text") from None
    rows = [
        (number, line.rstrip("\r").split("\t"))
        for number, line in enumerate(text.split("\n"), start=1)
        if line.strip()
    ]
    if not rows:
        raise InvalidInput(f"the labels file {path} is empty; it needs a header row")
    _, header = rows[0]
    header = [cell.strip() for cell in header]
    if len(header) < 2:
        raise InvalidInput(
            f"the labels file {path} needs a tab-separated header row with a clip column and "
            f"at least one label column; its first row has {len(header)} column"
        )
    no_header = (
        f"the labels file {path} has no header row (its first row {header[0]!r}, ... looks "
        "like data); add a first row such as 'clip<TAB>label'"
    )
    if header[0][:1].isdigit():
        raise InvalidInput(no_header)
    if any(not cell for cell in header):
        raise InvalidInput(f"the labels file {path}: the header row has an empty column name")
    if len(set(header)) != len(header):
        raise InvalidInput(f"the labels file {path}: the header row repeats a column name")
    kinds = header[1:]
    table: dict[str, dict[str, str]] = {}
    for number, cells in rows[1:]:
        cells = [cell.strip() for cell in cells]
        if len(cells) > len(header):
            raise InvalidInput(
                f"the labels file {path}, line {number}: {len(cells)} cells but the header has "
                f"{len(header)} columns"
            )
        key = cells[0]
        if not key:
            raise InvalidInput(f"the labels file {path}, line {number}: empty clip key")
        if key in table:
            raise InvalidInput(f"the labels file {path}, line {number}: clip {key!r} listed twice")
        table[key] = {kind: value for kind, value in zip(kinds, cells[1:], strict=False) if value}
    if table and all(any(row.get(k) == k for row in table.values()) for k in kinds):
        raise InvalidInput(no_header)
    return table


# JavaScript spells a named group (?<name>...) and its back-reference \k<name>; Python
# (?P<name>...) and (?P=name). Both are accepted here (and in the Upload page's script).
_JS_GROUP = re.compile(r"(?<!\\)((?:\\\\)*)\(\?<(?![=!])")
_JS_BACKREF = re.compile(r"(?<!\\)((?:\\\\)*)\\k<(\w+)>")


def python_regex(pattern: str) -> str:
    """``pattern`` with JavaScript's named-group spellings turned into Python's."""
    pattern = _JS_GROUP.sub(r"\1(?P<", pattern)
    return _JS_BACKREF.sub(r"\1(?P=\2)", pattern)


# A TSV column holding a value longer than this, or with more words, is free text (the CMU
# index's description, say), not tags: left out unless asked for by name.
FREE_TEXT_CHARACTERS = 40
FREE_TEXT_WORDS = 3


def is_free_text(value: str) -> bool:
    return len(value) > FREE_TEXT_CHARACTERS or len(value.split()) > FREE_TEXT_WORDS


def choose_label_columns(
    table: dict[str, dict[str, str]], columns: Iterable[str] | None = None
) -> tuple[dict[str, dict[str, str]], tuple[str, ...]]:
    """``table`` (from :func:`labels_from_tsv`) keeping only the label columns to use, and the
    columns left out.

    ``columns`` names them (comma-separated values allowed); by default every column is used
    except those holding free text: a value over :data:`FREE_TEXT_CHARACTERS` characters or
    :data:`FREE_TEXT_WORDS` words.

    Raises
    ------
    InvalidInput
        ``columns`` names a column the table does not have.
    """
    present: dict[str, None] = {}
    for row in table.values():
        present.update(dict.fromkeys(row))
    if columns is None:
        chosen = [
            kind
            for kind in present
            if not any(is_free_text(row[kind]) for row in table.values() if kind in row)
        ]
    else:
        chosen = [c.strip() for value in columns for c in value.split(",") if c.strip()]
        unknown = [c for c in chosen if c not in present]
        if unknown:
            raise InvalidInput(
                f"--label-columns: no column {', '.join(map(repr, unknown))} with values in the "
                f"labels file (its label columns: {', '.join(present) or 'none'})"
            )
    keep = set(chosen)
    left_out = tuple(kind for kind in present if kind not in keep)
    return {
        key: {k: v for k, v in row.items() if k in keep} for key, row in table.items()
    }, left_out


@lru_cache(maxsize=64)
def compile_label_regex(pattern: str) -> re.Pattern[str]:
    """``pattern`` compiled; it must have at least one named group, written
    ``(?P<kind>...)`` (Python) or ``(?<kind>...)`` (JavaScript).

    Raises
    ------
    InvalidInput
        Not a valid regular expression, or no named group.
    """
    try:
        compiled = re.compile(python_regex(pattern))
    except re.error as error:
        raise InvalidInput(f"invalid labels regex {pattern!r}: {error}") from None
    if not compiled.groupindex:
        raise InvalidInput(
            f"the labels regex {pattern!r} has no named group; name each label kind, e.g. "
            "(?P<content>[^_]+) or (?<content>[^_]+)"
        )
    return compiled


def labels_from_regex(pattern: str | re.Pattern[str], relative_path: str) -> dict[str, str]:
    """Label kind -> value from the named groups of ``pattern`` searched in ``relative_path``.

    Groups that did not take part in the match are left out; no match gives ``{}``. Paths are
    matched with ``/`` separators.
    """
    compiled = pattern if isinstance(pattern, re.Pattern) else compile_label_regex(pattern)
    match = compiled.search(relative_path.replace("\\", "/"))
    if match is None:
        return {}
    return {kind: value for kind, value in match.groupdict().items() if value is not None}
