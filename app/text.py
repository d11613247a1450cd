"""Text a user gives — names, labels, sources, licences, filters — that every database can
store: one check, applied where the text comes in, so both databases give the same answer."""

from __future__ import annotations

from app.errors import InvalidInput


def checked_text(field: str, value: str) -> str:
    """``value`` unchanged; :class:`InvalidInput` naming ``field`` when it holds a NUL
    character (PostgreSQL's text type cannot hold one; SQLite would, and the two databases
    must agree) or half of a UTF-16 surrogate pair (JSON's ``\\ud800``: no UTF-8 exists for
    it, so no database can store it)."""
    if "\x00" in value:
        raise InvalidInput(f"{field}: must not contain a NUL character (\\u0000)")
    if any("\ud800" <= c <= "\udfff" for c in value):
        raise InvalidInput(f"{field}: must be valid Unicode text (a lone surrogate is not)")
    return value
