"""The ``mocap-index`` command.

A subcommand is a :class:`~app.cli.command.Command`: a function ``run(args, settings) -> exit
code`` plus, when it takes options, a ``configure(parser)``::

    def _configure_eval(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--k", type=int, default=1)

    def _eval(args: argparse.Namespace, settings: Settings) -> int:
        ...

    EVAL = Command("eval", "measure retrieval accuracy", run=_eval, configure=_configure_eval)

listed in :data:`COMMANDS` (in the order ``mocap-index --help`` shows them).

Every subcommand takes ``--data-dir`` and ``--database-url``; any other setting comes from its
``MOCAP_*`` environment variable. The service and its schema are :mod:`app.cli.serve`; the
commands working on a library's stored clips :mod:`app.cli.library`. A command whose options
and report are long lives in a module of its own, imported when it runs (``import``:
:mod:`app.cli.importing`; ``eval``: :mod:`app.evaluation.cli`); the progress bar is
:mod:`app.cli.progress`.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from pydantic import ValidationError

from app.cli import library, serve
from app.cli.command import COMMAND_LINE_SETTINGS, Command
from app.config import Settings
from app.errors import MocapError

# -- eval --------------------------------------------------------------------------------


def _configure_eval(parser: argparse.ArgumentParser) -> None:
    from app.evaluation.cli import configure_parser

    configure_parser(parser)


def _eval(args: argparse.Namespace, settings: Settings) -> int:
    from app.evaluation.cli import run_eval

    return run_eval(args)


EVAL = Command(
    "eval",
    "score descriptors against labelled clips (leave-one-out 1-NN, Ward/BIC clustering)",
    configure=_configure_eval,
    run=_eval,
)


# -- import ------------------------------------------------------------------------------


def _configure_import(parser: argparse.ArgumentParser) -> None:
    from app.cli.importing import configure_import

    configure_import(parser)


def _import(args: argparse.Namespace, settings: Settings) -> int:
    from app.cli.importing import run_import_command

    return run_import_command(args, settings)


IMPORT = Command(
    "import",
    "import every clip under folders (BVH, ASF/AMC, FBX, glTF) in parallel; skips stored content",
    configure=_configure_import,
    run=_import,
)


COMMANDS: dict[str, Command] = {
    command.name: command
    for command in (
        serve.SERVE,
        serve.MIGRATE,
        library.REINDEX,
        EVAL,
        IMPORT,
        library.FILL_SYNTHETIC,
        library.DELETE,
        library.EXPORT,
    )
}


# -- entry point ---------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="mocap-index", description="Find similar motion-capture clips."
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}")
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


def version() -> str:
    """The installed package's version (the source tree's when not installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as installed

    try:
        return installed("mocap-index")
    except PackageNotFoundError:
        return "unknown (not installed)"


def settings_from(args: argparse.Namespace) -> Settings:
    """Settings from the environment, overridden by the options given on the command line."""
    fields = COMMAND_LINE_SETTINGS
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
