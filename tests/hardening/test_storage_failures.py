"""A full disk, a read-only database or a missing data directory: a clean 503 with a message,
nothing half stored, the database intact (``PRAGMA integrity_check``) and earlier clips
untouched. Tests run as root here, so ``chmod`` cannot make anything read-only: the failures
are made at the layer they come from (the blob store's ``os.replace`` raising ENOSPC, SQLite's
``max_page_count`` — its own "database or disk is full" — and ``query_only``, and directories
replaced by plain files as when a volume is not mounted).
"""

from __future__ import annotations

import errno
import os
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import event

from app.config import Settings
from app.errors import StorageUnavailable
from app.main import create_app
from app.services import blobs as blobs_module
from tests.hardening.live import database_problems, service_problems, unique_upload

DESCRIPTORS = 3


@pytest.fixture
def app_client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


def store_first_clip(client: TestClient) -> dict[str, Any]:
    response = client.post("/clips", files=unique_upload(0))
    assert response.status_code == 201, response.text
    return dict(response.json())


def assert_503(response: Any, *words: str) -> None:
    assert response.status_code == 503, response.text
    body = response.json()
    assert set(body) == {"error", "detail"} and body["error"] == "storage_unavailable", body
    for word in words:
        assert word in body["detail"], body["detail"]


def assert_intact(client: TestClient, settings: Settings, first: dict[str, Any]) -> None:
    """The earlier clip is whole, the library consistent, the database file sound."""
    assert client.get(f"/clips/{first['id']}").json()["content_hash"] == first["content_hash"]
    download = client.get(f"/clips/{first['id']}/file")
    assert download.status_code == 200 and download.content == unique_upload(0)["file"][1]
    assert service_problems(client) == []  # type: ignore[arg-type]
    assert database_problems(settings.data_dir, DESCRIPTORS) == []


@contextmanager
def sqlite_pragma(client: TestClient, pragma: Callable[[Any], str]) -> Iterator[None]:
    """Run ``pragma(connection)`` on every new database connection of the app, meanwhile."""
    engine = client.app.state.library.engine  # type: ignore[attr-defined]

    def on_connect(dbapi_connection: Any, _record: Any) -> None:
        cursor = dbapi_connection.cursor()
        cursor.execute(pragma(dbapi_connection))
        cursor.close()

    event.listen(engine, "connect", on_connect)
    engine.dispose()  # pooled connections go; new ones get the pragma
    try:
        yield
    finally:
        event.remove(engine, "connect", on_connect)
        engine.dispose()


def test_disk_full_while_writing_the_uploaded_files(
    app_client: TestClient, settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    first = store_first_clip(app_client)

    def no_space(*_args: object) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    fake_os = SimpleNamespace(**{**vars(os), "replace": no_space})
    monkeypatch.setattr(blobs_module, "os", fake_os)
    assert_503(app_client.post("/clips", files=unique_upload(1)), "No space left on device")
    monkeypatch.undo()
    assert app_client.get("/clips").json()["total"] == 1
    assert_intact(app_client, settings, first)
    # the disk has room again: the same upload goes in
    assert app_client.post("/clips", files=unique_upload(1)).status_code == 201


def test_database_full(app_client: TestClient, settings: Settings) -> None:
    first = store_first_clip(app_client)

    def full(connection: Any) -> str:
        pages = connection.execute("PRAGMA page_count").fetchone()[0]
        return f"PRAGMA max_page_count = {pages}"

    with sqlite_pragma(app_client, full):
        for n in range(1, 200):  # more clips than the free pages can hold
            response = app_client.post("/clips", files=unique_upload(n))
            if response.status_code == 503:
                break
            assert response.status_code == 201, response.text
        assert_503(response, "database")
        patch = app_client.patch(f"/clips/{first['id']}", json={"labels": ["x" * 90] * 50})
        assert patch.status_code in (200, 503), patch.text
        assert app_client.get("/health").status_code == 200
    assert_intact(app_client, settings, first)
    assert app_client.post("/clips", files=unique_upload(10)).status_code == 201


def test_read_only_database(app_client: TestClient, settings: Settings) -> None:
    first = store_first_clip(app_client)
    with sqlite_pragma(app_client, lambda _connection: "PRAGMA query_only = ON"):
        assert_503(app_client.post("/clips", files=unique_upload(1)), "database")
        assert_503(app_client.patch(f"/clips/{first['id']}", json={"name": "renamed"}))
        assert_503(app_client.delete(f"/clips/{first['id']}"))
        # reading still works
        assert app_client.get(f"/clips/{first['id']}").status_code == 200
        assert app_client.get("/search", params={"clip": first["id"]}).status_code == 200
        assert app_client.post("/search", files=unique_upload(2)).status_code == 200
        assert app_client.get("/health").status_code == 200
    assert app_client.get(f"/clips/{first['id']}").json()["name"] == first["name"]
    assert_intact(app_client, settings, first)
    # writable again, without a restart
    assert app_client.post("/clips", files=unique_upload(1)).status_code == 201


def test_files_directory_gone(app_client: TestClient, settings: Settings) -> None:
    """The volume holding files/ is not mounted: a plain file stands where the directory was."""
    first = store_first_clip(app_client)
    saved = settings.data_dir.parent / "files-saved"
    shutil.move(settings.files_dir, saved)
    settings.files_dir.write_bytes(b"not a directory")
    assert_503(app_client.post("/clips", files=unique_upload(1)), "cannot store")
    assert_503(app_client.get(f"/clips/{first['id']}/file"), "cannot be read")
    assert app_client.get("/health").status_code == 200
    settings.files_dir.unlink()
    shutil.move(saved, settings.files_dir)
    assert_intact(app_client, settings, first)


def break_index_directory(settings: Settings, client: TestClient) -> None:
    # The indexes' delayed save (a second after a change) would write into the folder while
    # it is being removed ("Directory not empty"): save now, nothing is left pending.
    client.app.state.library.save_indexes()  # type: ignore[attr-defined]
    shutil.rmtree(settings.index_dir)
    settings.index_dir.write_bytes(b"not a directory")


def check_after_restart(settings: Settings) -> None:
    settings.index_dir.unlink()
    restarted = settings.model_copy(update={"orphan_file_grace_seconds": 0})
    with TestClient(create_app(restarted)) as client:
        assert service_problems(client) == []  # type: ignore[arg-type]
    assert database_problems(settings.data_dir, DESCRIPTORS) == []


def test_delete_when_the_indexes_cannot_be_saved(settings: Settings) -> None:
    """The delete is committed: a cache that cannot be saved neither fails nor undoes it."""
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        first = store_first_clip(client)
        second = client.post("/clips", files=unique_upload(1)).json()
        break_index_directory(settings, client)
        assert client.delete(f"/clips/{first['id']}").status_code == 204
        assert client.get(f"/clips/{first['id']}").status_code == 404
        assert service_problems(client) == []  # type: ignore[arg-type]
        assert client.get("/search", params={"clip": second["id"]}).json()["results"] == []
    check_after_restart(settings)


def test_upload_when_the_indexes_cannot_be_saved(settings: Settings) -> None:
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        store_first_clip(client)
        break_index_directory(settings, client)
        uploaded = client.post("/clips", files=unique_upload(1))
        assert uploaded.status_code != 500, uploaded.text
        problems = service_problems(client)  # type: ignore[arg-type]
        check_after_restart(settings)  # whatever happened, a restart makes it right
        assert uploaded.status_code == 201, uploaded.text
        assert problems == []


def test_unusable_data_directory_stops_the_start_with_a_message(tmp_path: Path) -> None:
    not_a_dir = tmp_path / "data"
    not_a_dir.write_bytes(b"a file, not a directory")
    app = create_app(Settings(data_dir=not_a_dir))
    with pytest.raises(StorageUnavailable, match="cannot open the database"), TestClient(app):
        pass
