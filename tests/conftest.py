"""Shared fixtures: settings on a temporary data dir, a migrated database, an API client, and
the locations of the real motion files (small ones in tests/fixtures, the big sets in
../shared/data, which may be absent)."""

from __future__ import annotations

import collections
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import hypothesis
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from app.config import DATABASE_FILE_NAME, Settings
from app.db.migrate import upgrade
from app.db.session import create_db_engine
from tests import postgres

# No hypothesis deadline by default: how long an example takes on a loaded, shared machine is
# no verdict on the code (speed is measured under bench/).
hypothesis.settings.register_profile("mocap", deadline=None)
hypothesis.settings.load_profile("mocap")

REPO_ROOT = Path(__file__).resolve().parents[1]
FIXTURES_DIR = Path(__file__).resolve().parent / "fixtures"
TEST_CLIENT_HOST = "testserver"


def shared_data_dir() -> Path:
    """``../shared/data`` beside the repository, or ``$MOCAP_SHARED_DATA``."""
    override = os.environ.get("MOCAP_SHARED_DATA")
    return Path(override) if override else REPO_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session", autouse=True)
def _test_client_host() -> Iterator[None]:
    # Starlette's TestClient addresses every request to http://testserver: the one name the
    # tests add to the Host allow-list (Django's test runner does the same), for the whole
    # session so module-scoped apps get it too. Servers started in a subprocess
    # (tests/hardening/live.py) get no MOCAP_* variable: the real defaults.
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("MOCAP_ALLOWED_HOSTS", TEST_CLIENT_HOST)
        yield


@pytest.fixture(autouse=True)
def _no_mocap_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    # A developer's MOCAP_* variables must not leak into the settings tests build.
    for name in list(os.environ):
        if name.startswith("MOCAP_") and name not in ("MOCAP_SHARED_DATA", "MOCAP_ALLOWED_HOSTS"):
            monkeypatch.delenv(name)


@pytest.fixture(scope="session")
def migrated_sqlite_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SQLite database file at the newest revision, to copy (the tests on PostgreSQL clone
    a migrated template database the same way): migrating a new file takes ~0.25 s, and
    hundreds of tests start on a new library."""
    settings = Settings(data_dir=tmp_path_factory.mktemp("migrated") / "data")
    settings.data_dir.mkdir(parents=True)
    engine = create_db_engine(settings.sqlalchemy_url)
    upgrade(engine)
    engine.dispose()  # the last connection folds the write-ahead log into the file
    return settings.data_dir / DATABASE_FILE_NAME


def new_sqlite_settings(data_dir: Path, migrated_file: Path) -> Settings:
    """Settings on ``data_dir`` holding a copy of ``migrated_file``: a new, empty library."""
    data_dir.mkdir(parents=True)
    shutil.copyfile(migrated_file, data_dir / DATABASE_FILE_NAME)
    return Settings(data_dir=data_dir)


@pytest.fixture
def settings(tmp_path: Path, migrated_sqlite_file: Path) -> Settings:
    """Settings on a fresh temporary data directory (SQLite file, files/, indexes/)."""
    return new_sqlite_settings(tmp_path / "data", migrated_sqlite_file)


@pytest.fixture
def engine(settings: Settings) -> Iterator[Engine]:
    """An engine on a temporary SQLite file migrated to the newest revision."""
    engine = create_db_engine(settings.sqlalchemy_url)
    upgrade(engine)
    yield engine
    engine.dispose()


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    """The real app over HTTP; entering the client runs the lifespan (Alembic migration of a
    fresh SQLite file, index loading)."""
    from app.main import create_app

    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture
def fixtures_dir() -> Path:
    return FIXTURES_DIR


class SharedData:
    """Folders and files of the real datasets, each asked for by name, so a test skips when
    the one it needs is missing (naming it), not only when ``../shared/data`` is."""

    def __init__(self, root: Path) -> None:
        self.root = root

    def __call__(self, *parts: str) -> Path:
        """``shared_data("bandai-ds1", "data")``: that path, or a skip naming it."""
        path = self.root.joinpath(*parts)
        if not path.exists():
            pytest.skip(
                f"real motion data not found: {path} (../shared/data beside the repository, "
                "or set MOCAP_SHARED_DATA)"
            )
        return path


@pytest.fixture(scope="session")
def shared_data() -> SharedData:
    """The real datasets (``../shared/data``): ``shared_data("cmu", "asf-amc")`` gives a
    folder of them, or skips the test when that folder is absent."""
    return SharedData(shared_data_dir())


@pytest.fixture(scope="session")
def postgres_cluster() -> Iterator[postgres.Cluster]:
    """A throwaway PostgreSQL 15 server for the session (skips, or fails in CI, without one)."""
    cluster = postgres.start_cluster()
    try:
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture
def postgres_url(postgres_cluster: postgres.Cluster) -> str:
    """A fresh database at the newest schema revision on the session's PostgreSQL server."""
    return postgres_cluster.new_database()


# Scheduling only: pytest-xdist (``--dist loadfile``) hands whole files to its workers in
# the order it is given them (``--no-loadscope-reorder``: its own order, most tests first,
# left a long file of few tests, the OpenAPI fuzz or a browser file, for the end while the
# other workers had nothing left). The longest files go first, by the worker-seconds of
# ``--durations=0`` runs (the last: the junit times of a quiet first phase, 2026-11-27), then
# the other browser files, then the rest by their number of tests (xdist's own order); the
# order inside a file is unchanged.
LONGEST_FILES_FIRST = (
    "tests/services/test_describe.py",
    "tests/api/test_everyday.py",
    "tests/motion/test_mapping_names.py",
    "tests/api/test_wild_more_devset.py",
    "tests/ui/test_everyday_ui.py",
    "tests/hardening/test_openapi_fuzz.py",
    "tests/motion/test_mapping_rest.py",
    "tests/motion/test_mapping_probes.py",
    "tests/ui/test_pages_browser.py",
    "tests/api/test_readme.py",
    "tests/ui/test_downloads_browser.py",
    "tests/cli/test_import_process.py",
    "tests/hardening/test_crash_import.py",
    "tests/test_importer.py",
    "tests/motion/test_mapping_odd_rest.py",
    "tests/ui/",
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    def file_of(item: pytest.Item) -> str:
        return item.nodeid.split("::", 1)[0]

    tests_in = collections.Counter(file_of(item) for item in items)

    def rank(item: pytest.Item) -> tuple[int, int]:
        for place, prefix in enumerate(LONGEST_FILES_FIRST):
            if item.nodeid.startswith(prefix):
                return place, 0
        return len(LONGEST_FILES_FIRST), -tests_in[file_of(item)]

    items.sort(key=rank)  # stable: a file's tests stay together and in order
