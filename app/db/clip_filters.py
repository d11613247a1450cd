"""Which clips a listing, a bulk change or a search filter keeps, in SQL.

A :class:`ClipFilter` gathers what ``GET /clips``, ``POST /clips/labels`` and ``DELETE
/clips`` can select by: ids, labels (all of them, any case: :mod:`app.db.label_filters`), a
licence filter (:mod:`app.licences`) and the words of a text search. The searches take the
label and licence filters only, from the in-memory catalogue (:mod:`app.index.catalogue`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

from sqlalchemy import and_, exists, func, not_, or_, select

from app.db.label_filters import LabelFilter, label_conditions
from app.db.models import Clip, ClipFile, ClipLabel
from app.db.rows import Executor
from app.errors import InvalidInput
from app.labels import label_filter, refuse_nul
from app.licences import LicenceArg, LicenceFilter, licence_filter

MAX_ID = 2**63 - 1  # ids are signed 64-bit integers in every database


def search_words(text: str | None) -> tuple[str, ...]:
    """The words of a text search (split on white space, lower case, each once)."""
    words = tuple(dict.fromkeys(word.lower() for word in (text or "").split()))
    refuse_nul("q", words)
    return words


@dataclass(frozen=True)
class ClipFilter:
    """Clips that are among ``ids`` (when given), carry every label of ``label``, pass
    ``licence`` and hold every word of ``words`` (see :func:`text_conditions`)."""

    ids: tuple[int, ...] | None = None
    label: LabelFilter = None
    licence: LicenceFilter = field(default_factory=LicenceFilter)
    words: tuple[str, ...] = ()
    # The criteria the caller sent (``label``, ``licence``, ``q``), even empty ones: what an
    # error about an empty selection names.
    given: tuple[str, ...] = field(default=(), compare=False)

    @classmethod
    def of(
        cls,
        *,
        ids: Sequence[int] | None = None,
        label: LabelFilter = None,
        licence: LicenceArg = None,
        q: str | None = None,
    ) -> ClipFilter:
        """The filter of these criteria (:class:`InvalidInput` for an id no clip can have:
        ids are positive 64-bit integers)."""
        for clip_id in ids or ():
            if not 0 < clip_id <= MAX_ID:
                raise InvalidInput(f"ids: {clip_id} is no clip id (1 to {MAX_ID})")
        sent = {"label": label, "licence": licence, "q": q}
        return cls(
            None if ids is None else tuple(int(i) for i in ids),
            label,
            licence_filter(licence),
            search_words(q),
            tuple(name for name, value in sent.items() if value is not None),
        )

    def __bool__(self) -> bool:
        """Whether it filters at all (an empty id list selects nothing: it filters)."""
        return any((self.ids is not None, label_filter(self.label), self.licence, self.words))


def _like(word: str) -> str:
    """A LIKE pattern matching ``word`` anywhere, with ``%``, ``_`` and ``\\`` taken literally."""
    escaped = word.replace("\\", "\\\\").replace("%", "\\%").replace("_", "\\_")
    return f"%{escaped}%"


def text_conditions(words: Sequence[str]) -> list[Any]:
    """One condition per word: it appears (any case) in the clip's name, one of its file
    names, one of its labels, its source or its licence."""
    conditions = []
    for word in words:
        pattern = _like(word)
        conditions.append(
            or_(
                func.lower(Clip.name).like(pattern, escape="\\"),
                func.lower(Clip.source).like(pattern, escape="\\"),
                func.lower(Clip.licence).like(pattern, escape="\\"),
                exists().where(
                    ClipLabel.clip_id == Clip.id,
                    func.lower(ClipLabel.label).like(pattern, escape="\\"),
                ),
                exists().where(
                    ClipFile.clip_id == Clip.id,
                    func.lower(ClipFile.filename).like(pattern, escape="\\"),
                ),
            )
        )
    return conditions


def licence_condition(licence: LicenceFilter) -> list[Any]:
    """``[condition]`` keeping the clips ``licence`` allows (the database lowers both sides,
    so its own idea of case applies to both), or ``[]``."""
    if not licence:
        return []
    stored = func.lower(func.trim(Clip.licence))
    parts: list[Any] = []
    if licence.keep:
        parts.append(stored.in_([func.lower(value) for value in licence.keep]))
    if licence.drop:
        parts.append(
            or_(Clip.licence.is_(None), not_(stored.in_([func.lower(v) for v in licence.drop])))
        )
    return [and_(*parts)]


def clip_conditions(executor: Executor, selection: ClipFilter) -> list[Any]:
    """WHERE conditions on ``clips`` for ``selection``."""
    conditions = label_conditions(executor, selection.label)
    conditions += licence_condition(selection.licence)
    conditions += text_conditions(selection.words)
    if selection.ids is not None:
        conditions.append(Clip.id.in_(sorted(set(selection.ids))))
    return conditions


def selected_ids(executor: Executor, selection: ClipFilter) -> list[int]:
    """Ids (ascending) of the clips ``selection`` keeps."""
    query = select(Clip.id).where(*clip_conditions(executor, selection)).order_by(Clip.id)
    return [int(i) for i in executor.scalars(query)]
