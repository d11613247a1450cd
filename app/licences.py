"""What a ``licence`` filter means, for every route that takes one (``GET /clips``, both
searches, bulk labels and deletes).

A clip has at most one licence, free text (``CC BY-NC 4.0``, ``free for any use``). A filter
is one or more values, repeated and/or comma-separated, each trimmed and compared with the
whole licence in any case:

* ``licence=CC0,CC BY 4.0`` keeps the clips whose licence is one of those;
* ``licence=!CC BY-NC 4.0`` (a leading ``!``) drops the clips with that licence, and keeps the
  others, those without a licence included;
* both at once keep the first kind minus the second; empty values are no filter.

So a studio hides what it may not ship with one parameter. This module holds the rule; the
SQL (:mod:`app.db.clip_filters`) and any in-memory filter follow it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from app.labels import refuse_nul

EXCLUDE = "!"


def licence_key(licence: str) -> str:
    """The form licences are compared by: trimmed, lower case."""
    return licence.strip().lower()


@dataclass(frozen=True)
class LicenceFilter:
    """``keep``: licences a clip's must be one of (none: any); ``drop``: licences it must not
    be. Each as given (trimmed), compared by :func:`licence_key`."""

    keep: tuple[str, ...] = ()
    drop: tuple[str, ...] = ()

    def __bool__(self) -> bool:
        return bool(self.keep or self.drop)

    def allows(self, licence: str | None) -> bool:
        """Whether a clip of ``licence`` (``None``: none given) passes the filter."""
        key = None if licence is None else licence_key(licence)
        if self.keep and key not in {licence_key(k) for k in self.keep}:
            return False
        return key is None or key not in {licence_key(d) for d in self.drop}


LicenceArg = LicenceFilter | str | Iterable[str] | None
"""A ``licence`` filter as given: values (repeated, comma-separated) or a parsed filter."""


def licence_filter(values: LicenceArg) -> LicenceFilter:
    """The filter ``values`` ask for (see the module docstring); ``LicenceFilter()`` for none."""
    if isinstance(values, LicenceFilter):
        return values
    if values is None:
        return LicenceFilter()
    if isinstance(values, str):
        values = [values]
    keep: dict[str, str] = {}
    drop: dict[str, str] = {}
    for value in values:
        for item in value.split(","):
            item = item.strip()
            excluded = item.startswith(EXCLUDE)
            text = item[len(EXCLUDE) :].strip() if excluded else item
            if text:
                (drop if excluded else keep).setdefault(licence_key(text), text)
    refuse_nul("licence", [*keep.values(), *drop.values()])
    return LicenceFilter(tuple(keep.values()), tuple(drop.values()))
