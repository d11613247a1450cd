"""``mocap-index serve`` (the web service, in one process or several forked workers) and
``mocap-index migrate`` (its database schema)."""

from __future__ import annotations

import argparse
import os
import sys

from app.cli.command import COMMAND_LINE_SETTINGS, Command
from app.config import Settings

# -- serve ---------------------------------------------------------------------------------


def _configure_serve(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", help="address to bind (default 127.0.0.1, MOCAP_HOST)")
    parser.add_argument("--port", type=int, help="port (default 8000, MOCAP_PORT)")
    parser.add_argument(
        "--workers",
        type=int,
        help="processes answering requests (default 1, MOCAP_WORKERS; one per core is fastest)",
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


SERVE = Command(
    "serve",
    "start the web service (the web UI at /, the API docs at /docs)",
    configure=_configure_serve,
    run=_serve,
)


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


MIGRATE = Command(
    "migrate",
    "create or upgrade the database schema (the service also does it at start)",
    run=_migrate,
)
