"""Apply the Alembic migrations in ``migrations/`` — the only way the schema is created.

Alembic itself (~0.3 s to import, and its script directory to read) is loaded only when a
database is not at the newest revision: :func:`upgrade` first compares the revision stored
in ``alembic_version`` with the newest one named by the files of ``migrations/versions``
(read as text), so every start of an up-to-date library skips it.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, text
from sqlalchemy.exc import SQLAlchemyError

if TYPE_CHECKING:
    from alembic.config import Config

log = logging.getLogger(__name__)

# migrations/ sits beside app/ (repository root), as alembic.ini expects.
MIGRATIONS_DIR = Path(__file__).resolve().parents[2] / "migrations"
MIGRATION_LOCK = 0x6D6F636170  # "mocap": the advisory lock id migrations take on PostgreSQL
# A migration file's own revision and the one it follows, as `alembic revision` writes them.
_REVISION = re.compile(r'^revision(?:\s*:[^=]*)?\s*=\s*["\']([^"\']+)["\']', re.MULTILINE)
_DOWN_REVISION = re.compile(
    r'^down_revision(?:\s*:[^=]*)?\s*=\s*(None|["\']([^"\']+)["\'])', re.MULTILINE
)


def alembic_config() -> Config:
    """An Alembic configuration pointing at ``migrations/`` (no alembic.ini needed)."""
    from alembic.config import Config

    if not (MIGRATIONS_DIR / "env.py").is_file():
        raise RuntimeError(
            f"Alembic migrations not found at {MIGRATIONS_DIR}; install mocap-index from its "
            "source tree (pip install -e .) so migrations/ sits beside app/"
        )
    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    return config


def head_in_files() -> str | None:
    """The newest revision of ``migrations/versions`` read from the files as text: the one
    no other follows. ``None`` when that is not one revision (no files, a file not written
    the usual way, two heads): then only Alembic can tell."""
    revisions: set[str] = set()
    followed: set[str] = set()
    for path in (MIGRATIONS_DIR / "versions").glob("*.py"):
        source = path.read_text(encoding="utf-8")
        revision, down = _REVISION.search(source), _DOWN_REVISION.search(source)
        if revision is None or down is None:
            return None
        revisions.add(revision.group(1))
        if down.group(2) is not None:
            followed.add(down.group(2))
    heads = revisions - followed
    return next(iter(heads)) if len(heads) == 1 else None


def _stored_revision(engine: Engine) -> str | None:
    """The revision in ``alembic_version`` read with plain SQL (``None``: no table yet, or not
    exactly one row)."""
    try:
        with engine.connect() as connection:
            rows = connection.execute(text("SELECT version_num FROM alembic_version")).all()
    except SQLAlchemyError:
        return None
    return str(rows[0][0]) if len(rows) == 1 else None


def upgrade(engine: Engine, revision: str = "head") -> None:
    """Bring the database behind ``engine`` to ``revision`` (default: the newest)."""
    if revision == "head":
        newest = head_in_files()
        if newest is not None and _stored_revision(engine) == newest:
            return  # at the newest already: no Alembic
    from alembic import command
    from alembic.runtime.migration import MigrationContext

    config = alembic_config()
    # Two processes starting together (replicas) migrate one after the other: IMMEDIATE on
    # SQLite takes the write lock; on PostgreSQL a transaction-scoped advisory lock.
    with engine.execution_options(sqlite_begin="IMMEDIATE").begin() as connection:
        if connection.dialect.name == "postgresql":
            connection.exec_driver_sql(f"SELECT pg_advisory_xact_lock({MIGRATION_LOCK})")
        before = MigrationContext.configure(connection).get_current_revision()
        config.attributes["connection"] = connection
        command.upgrade(config, revision)
        after = MigrationContext.configure(connection).get_current_revision()
    if after != before:
        log.info("database migrated from revision %s to %s", before or "(empty)", after)


def downgrade(engine: Engine, revision: str) -> None:
    """Take the database back to ``revision`` (``"base"``: no tables)."""
    from alembic import command

    config = alembic_config()
    with engine.execution_options(sqlite_begin="IMMEDIATE").begin() as connection:
        config.attributes["connection"] = connection
        command.downgrade(config, revision)


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (``None`` when it was never migrated)."""
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def head_revision() -> str | None:
    """The newest revision in ``migrations/`` (as Alembic reads it)."""
    from alembic.script import ScriptDirectory

    return ScriptDirectory.from_config(alembic_config()).get_current_head()
