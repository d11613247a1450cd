"""The ``mocap-index`` command.

Subcommands register themselves with :func:`command`; adding one is a function
``run(args, settings) -> exit code`` plus, when it takes options, a ``configure(parser)``::

    def _configure_eval(parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--k", type=int, default=1)

    @command("eval", "measure retrieval accuracy", configure=_configure_eval)
    def _eval(args: argparse.Namespace, settings: Settings) -> int:
        ...

Every subcommand takes ``--data-dir`` and ``--database-url``; any other setting comes from its
``MOCAP_*`` environment variable. A command whose options and report are long lives in a module
of its own, imported when it runs (``import``: :mod:`app.cli_import`; ``eval``:
:mod:`app.evaluation.cli`); the progress bar is :mod:`app.cli_progress`.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from app.cli_progress import ProgressBar
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
    parser.add_argument(
        "--workers",
        type=int,
        help="processes answering requests (default 1, MOCAP_WORKERS; one per core is fastest)",
    )


@command(
    "serve",
    "start the web service (the web UI at /, the API docs at /docs)",
    configure=_configure_serve,
)
def _serve(args: argparse.Namespace, settings: Settings) -> int:
    import uvicorn

    # An unspecified address is reachable locally as localhost; IPv6 needs brackets.
    host = {"0.0.0.0": "localhost", "::": "localhost", "": "localhost"}.get(
        settings.host, settings.host
    )
    base = f"http://{f'[{host}]' if ':' in host else host}:{settings.port}"
    if args.workers is not None:
        if not 1 <= args.workers <= 64:
            print("mocap-index: --workers must be between 1 and 64", file=sys.stderr)
            return 2
        settings = settings.model_copy(update={"workers": args.workers})
    print(f"mocap-index: data in {settings.data_dir}", file=sys.stderr)
    print(f"mocap-index: web UI at {base}/", file=sys.stderr)
    print(f"mocap-index: API docs at {base}/docs", file=sys.stderr)
    if settings.workers == 1:
        from app.main import create_app  # not in a parent of workers: they import it

        uvicorn.run(
            create_app(settings),
            host=settings.host,
            port=settings.port,
            log_level=settings.log_level,
        )
        return 0
    # Several processes on one port: each opens the library like a replica would. The
    # database is migrated once, here, so they do not race to it; they read their settings
    # from the environment they inherit, with this command's options written into it.
    from app.db.migrate import upgrade
    from app.db.session import create_db_engine

    engine = create_db_engine(settings.sqlalchemy_url)
    try:
        upgrade(engine)
    finally:
        engine.dispose()
    for name in COMMAND_LINE_SETTINGS:
        value = getattr(settings, name)
        if value is not None:
            os.environ[f"MOCAP_{name.upper()}"] = str(value)
    print(f"mocap-index: {settings.workers} worker processes", file=sys.stderr)
    if _fork_workers():  # every worker is a copy of this process: what it holds, they hold
        from app.main import access_table, create_app

        # The guard's table, built from the app's OpenAPI schema (0.3-1 s of CPU): else each
        # worker builds it at its first request. No library is opened here.
        access_table(create_app(settings))
    uvicorn.run(
        "app.main:app_from_environment",
        factory=True,
        workers=settings.workers,
        host=settings.host,
        port=settings.port,
        log_level=settings.log_level,
    )
    return 0


def _fork_workers() -> bool:
    """Have uvicorn fork its workers from this process instead of spawning fresh
    interpreters, and say whether it will. A spawned worker imports the application again
    (~2.2 s of CPU a worker at start, issue 23); a forked one starts from this process's
    modules, imported once before the workers start (their pages shared until written).
    Safe here: this process runs no thread yet, and numpy's BLAS runs one (app/__init__.py),
    so no lock is held across the fork. uvicorn takes its workers' start method from one
    module attribute; without it (another uvicorn), or without ``fork``, workers spawn as
    before."""
    import multiprocessing

    from uvicorn import _subprocess

    if not hasattr(_subprocess, "spawn") or "fork" not in multiprocessing.get_all_start_methods():
        return False
    _subprocess.spawn = multiprocessing.get_context("fork")  # type: ignore[assignment]
    return True


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
    progress = parser.add_mutually_exclusive_group()
    progress.add_argument(
        "--progress",
        action="store_true",
        default=None,
        help="show a progress bar (default: when stderr is a terminal)",
    )
    progress.add_argument("--no-progress", dest="progress", action="store_false")


@command(
    "reindex",
    "recompute outdated descriptor vectors and rebuild the indexes (stop the service first)",
    configure=_configure_reindex,
)
def _reindex(args: argparse.Namespace, settings: Settings) -> int:
    from app.services.library import open_library
    from app.services.reindex import reindex

    show = sys.stderr.isatty() if args.progress is None else args.progress
    bar = ProgressBar("reindexing")

    def progress(done: int, total: int, clip: Any) -> None:
        bar.total = total
        bar.set_done(done)

    library = open_library(settings)
    try:
        report = reindex(library, everything=args.all, progress=progress if show else None)
    finally:
        bar.stop()
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


# -- import ------------------------------------------------------------------------------


def _configure_import(parser: argparse.ArgumentParser) -> None:
    from app.cli_import import configure_import

    configure_import(parser)


@command(
    "import",
    "import every clip under folders (BVH, ASF/AMC, FBX, glTF) in parallel; skips stored content",
    configure=_configure_import,
)
def _import(args: argparse.Namespace, settings: Settings) -> int:
    from app.cli_import import run_import_command

    return run_import_command(args, settings)


# -- fill-synthetic ------------------------------------------------------------------------


def _configure_fill(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--count",
        type=int,
        required=True,
        help="clips the library should hold afterwards (synthetic ones are added up to it)",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--noise",
        type=float,
        default=0.25,
        help="noise around the real clips, in standard deviations of each number (0.25)",
    )


@command(
    "fill-synthetic",
    "add synthetic clips (label and format 'synthetic', no stored file) for benchmarks. They "
    "show up in searches: use a separate --data-dir (a copy of a library), never your own "
    "library; 'mocap-index delete --label synthetic --yes' removes them",
    configure=_configure_fill,
)
def _fill_synthetic(args: argparse.Namespace, settings: Settings) -> int:
    from app.services.synthetic import fill_synthetic

    if args.count < 0:
        print("mocap-index: --count must not be negative", file=sys.stderr)
        return 2
    result = fill_synthetic(
        settings,
        args.count,
        seed=args.seed,
        noise=args.noise,
        report=lambda message: print(message, file=sys.stderr),
    )
    print(
        f"added {result.added} synthetic clips in {result.seconds:.1f} s; the library holds "
        f"{result.total} clips; indexes: "
        + ", ".join(f"{name} {kind}" for name, kind in result.index_kinds.items())
    )
    return 0


# -- delete --------------------------------------------------------------------------------


def _configure_delete(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--label",
        action="append",
        required=True,
        metavar="LABEL",
        help="delete the clips carrying this label (repeat, or separate with commas, for "
        "clips carrying all of them; any case)",
    )
    parser.add_argument(
        "--yes",
        action="store_true",
        help="really delete; without it, only say how many clips would go (exit status 1)",
    )


@command(
    "delete",
    "delete every clip carrying a label (e.g. the synthetic ones), with its files and vectors",
    configure=_configure_delete,
)
def _delete(args: argparse.Namespace, settings: Settings) -> int:
    from app.labels import label_filter
    from app.services import clips as clip_service
    from app.services.library import open_library

    labels = label_filter(args.label)
    if not labels:
        print("mocap-index: --label: name the label of the clips to delete", file=sys.stderr)
        return 2
    named = ", ".join(labels)
    library = open_library(settings)
    try:
        if not args.yes:
            count = len(clip_service.clips_with_labels(library, labels))
            print(
                f"would delete {count} clip{'s' if count != 1 else ''} labelled {named} "
                f"(of {library.clip_count()}); add --yes to delete them"
            )
            return 1 if count else 0
        deleted = clip_service.delete_clips_with(library, labels)
        remaining = library.clip_count()
    finally:
        library.close()
    print(f"deleted {deleted} clip{'s' if deleted != 1 else ''} labelled {named}; {remaining} left")
    return 0


# -- export ----------------------------------------------------------------------------------


def _configure_export(parser: argparse.ArgumentParser) -> None:
    which = parser.add_mutually_exclusive_group(required=True)
    which.add_argument(
        "--clip",
        action="extend",
        nargs="+",
        type=int,
        metavar="ID",
        help="the clips to export, by id (several after one --clip, or repeat it)",
    )
    which.add_argument(
        "--label",
        action="append",
        metavar="LABEL",
        help="export every clip carrying this label (repeat, or separate with commas, for "
        "clips carrying all of them)",
    )
    parser.add_argument("--format", choices=("bvh", "fbx", "glb"), default="bvh")
    parser.add_argument("--rig", type=int, metavar="ID", help="retarget onto this stored rig")
    parser.add_argument("--root", choices=("keep", "in-place", "extract"), default="keep")
    parser.add_argument("--units", choices=("cm", "m", "in"), help="BVH/FBX lengths")
    parser.add_argument("--fps", type=float, help="frame rate of the files")
    parser.add_argument(
        "--out", type=Path, required=True, metavar="DIR", help="folder for the files"
    )
    parser.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="show a progress bar (default: when stderr is a terminal)",
    )


@command(
    "export",
    "write clips as BVH, FBX or GLB files (on a rig, root motion handled) into a folder",
    configure=_configure_export,
)
def _export(args: argparse.Namespace, settings: Settings) -> int:
    from app.labels import label_filter
    from app.services.export import Exporter, ExportOptions, Manifest, export_each, export_items
    from app.services.library import open_library

    options = ExportOptions(
        format=args.format, units=args.units, fps=args.fps, root=args.root, rig=args.rig
    )
    show = sys.stderr.isatty() if args.progress is None else args.progress
    bar = ProgressBar("exporting")
    library = open_library(settings)
    failed = written = 0
    try:
        exporter = Exporter(library, options)
        if args.clip:
            items = export_items(library, clips=[(c, None, None) for c in args.clip])
        else:
            items = export_items(library, labels=list(label_filter(args.label)))
        args.out.mkdir(parents=True, exist_ok=True)
        manifest = Manifest(options)
        bar.total = len(items)
        for done, (item, exported, error) in enumerate(export_each(exporter, items), start=1):
            filename = manifest.add(item, exported, error)
            if exported is not None and filename is not None:
                (args.out / filename).write_bytes(exported.data)
                written += 1
            else:
                failed += 1
                print(f"clip {item.clip.id}: {error}", file=sys.stderr)
            if show:
                bar.set_done(done)
        (args.out / "manifest.csv").write_text(manifest.text(), encoding="utf-8")
    finally:
        bar.stop()
        library.close()
    print(f"wrote {written} files and manifest.csv to {args.out}; {failed} failed")
    return 1 if failed else 0


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


# Settings a command-line option may give (the rest come from MOCAP_* variables only).
COMMAND_LINE_SETTINGS = ("data_dir", "database_url", "host", "port")


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


if __name__ == "__main__":
    sys.exit(main())
