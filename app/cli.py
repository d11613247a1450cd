"""The ``mocap-index`` command.

Subcommands register themselves with :func:`command`; adding one is a function
``run(args, settings) -> exit code`` plus, when it takes options, a ``configure(parser)``::

    def _configure_eval(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--k", type=int, default=1)

    @command("eval", "measure retrieval accuracy", configure=_configure_eval)
    def _eval(args: argparse.Namespace, settings: Settings) -> int:
        ...

Every subcommand takes ``--data-dir`` and ``--database-url``; any other setting comes from its
``MOCAP_*`` environment variable.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError

from app.config import Settings
from app.errors import MocapError

Run = Callable[[argparse.Namespace, Settings], int]
Configure = Callable[[argparse.ArgumentParser], None]


@dataclass(frozen=True)
class Command:
    name: str
    help: str
    run: Run
    configure: Configure | None = None


COMMANDS: dict[str, Command] = {}


def command(name: str, help: str, *, configure: Configure | None = None) -> Callable[[Run], Run]:
    """Register ``run`` as the subcommand ``name``."""

    def register(run: Run) -> Run:
        COMMANDS[name] = Command(name, help, run, configure)
        return run

    return register


# -- serve ---------------------------------------------------------------------------------


def _configure_serve(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="address to bind (default 127.0.0.1, MOCAP_HOST)")
    parser.add_argument("--port", type=int, help="port (default 8000, MOCAP_PORT)")


@command("serve", "start the web service (API and its docs at /docs)", configure=_configure_serve)
def _serve(args: argparse.Namespace, settings: Settings) -> int:
    import uvicorn

    from app.main import create_app

    print(f"mocap-index: data in {settings.data_dir}", file=sys.stderr)
    print(f"mocap-index: API docs at http://{settings.host}:{settings.port}/docs", file=sys.stderr)
    uvicorn.run(
        create_app(settings),
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
    )
    return 0


# -- migrate -------------------------------------------------------------------------------


@command("migrate", "create or upgrade the database schema (the service also does it at start)")
def _migrate(args: argparse.Namespace, settings: Settings) -> int:
    from app.db.migrate import current_revision, upgrade
    from app.db.session import create_db_engine

    engine = create_db_engine(settings.sqlalchemy_url)
    try:
        upgrade(engine)
        print(f"database at revision {current_revision(engine)}: {engine.url!r}")
    finally:
        engine.dispose()
    return 0


# -- reindex -------------------------------------------------------------------------------


def _configure_reindex(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--all",
        action="store_true",
        help="recompute every vector, not only the missing or outdated ones",
    )


@command(
    "reindex",
    "recompute outdated descriptor vectors and rebuild the indexes (stop the service first)",
    configure=_configure_reindex,
)
def _reindex(args: argparse.Namespace, settings: Settings) -> int:
    from app.services.library import open_library
    from app.services.reindex import reindex

    library = open_library(settings)
    try:
        report = reindex(
            library,
            everything=args.all,
            progress=lambda done, total, clip: print(
                f"[{done}/{total}] {clip.name}", file=sys.stderr
            ),
        )
    finally:
        library.close()
    for clip_id, why in report.failed.items():
        print(f"clip {clip_id}: {why}", file=sys.stderr)
    sizes = ", ".join(f"{name} {size}" for name, size in report.index_sizes.items())
    print(f"recomputed {report.recomputed} clips, {len(report.failed)} failed; indexes: {sizes}")
    return 1 if report.failed else 0


def _configure_eval(parser: argparse.ArgumentParser) -> None:
    from app.evaluation.cli import configure_parser

    configure_parser(parser)


@command(
    "eval",
    "score descriptors against labelled clips (leave-one-out 1-NN, Ward/BIC clustering)",
    configure=_configure_eval,
)
def _eval(args: argparse.Namespace, settings: Settings) -> int:
    from app.evaluation.cli import run_eval

    return run_eval(args)


# -- entry point ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocap-index", description="Find similar motion-capture clips."
    )
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--data-dir", type=Path, help="data directory (default ./data, MOCAP_DATA_DIR)"
    )
    common.add_argument(
        "--database-url",
        help="SQLAlchemy URL (default: SQLite in the data directory, MOCAP_DATABASE_URL)",
    )
    subcommands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for cmd in COMMANDS.values():
        sub = subcommands.add_parser(
            cmd.name, help=cmd.help, description=cmd.help, parents=[common]
        )
        if cmd.configure is not None:
            cmd.configure(sub)
        sub.set_defaults(run=cmd.run)
    return parser


def settings_from(args: argparse.Namespace) -> Settings:
    """Settings from the environment, overridden by the options given on the command line."""
    fields = ("data_dir", "database_url", "host", "port")
    overrides = {f: getattr(args, f) for f in fields if getattr(args, f, None) is not None}
    return Settings(**overrides)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Our own messages (index rebuilds, migrations) at INFO; libraries only when they warn.
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s:     %(name)s: %(message)s")
    logging.getLogger("app").setLevel(logging.INFO)
    try:
        settings = settings_from(args)
    except ValidationError as error:
        print(f"mocap-index: bad setting: {error}", file=sys.stderr)
        return 2
    try:
        code: int = args.run(args, settings)
    except MocapError as error:
        print(f"mocap-index: {error.detail}", file=sys.stderr)
        return 1
    return code


if __name__ == "__main__":
    sys.exit(main())
