"""Where the labels of a clip come from: a TSV table keyed by clip, or a regex over its path.

* :func:`labels_from_tsv` reads a tab-separated table whose first row is a header: the first
  column holds the clip key (the file stem, e.g. ``02_01``), every other column is a *label
  kind* (e.g. ``coarse``, ``fine``). An empty cell means "no value of that kind".
* :func:`labels_from_regex` applies a regular expression with named groups to a clip's
  relative path (``re.search``, so it may match anywhere); each named group that matched is a
  label kind. E.g. ``dataset-1_(?P<content>[^_]+)_(?P<style>[^_]+)_\\d+`` gives the Bandai
  ``content`` and ``style``.

Both raise :class:`~app.errors.InvalidInput` with a message a user can act on.
"""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

from app.errors import InvalidInput


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


@lru_cache(maxsize=64)
def compile_label_regex(pattern: str) -> re.Pattern[str]:
    """``pattern`` compiled; it must have at least one named group.

    Raises
    ------
    InvalidInput
        Not a valid regular expression, or no ``(?P<kind>...)`` group.
    """
    try:
        compiled = re.compile(pattern)
    except re.error as error:
        raise InvalidInput(f"invalid labels regex {pattern!r}: {error}") from None
    if not compiled.groupindex:
        raise InvalidInput(
            f"the labels regex {pattern!r} has no named group; name each label kind, e.g. "
            "(?P<content>[^_]+)"
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
