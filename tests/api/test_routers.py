"""An app takes a module's router's routes as they are unless it adds to them
(app/api/routers.py): FastAPI builds an included router's routes again for each app."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from app.api import clips
from app.config import Settings
from app.main import create_app


def test_apps_share_the_modules_routes_and_a_key_for_reads_still_guards_them(
    tmp_path: Path,
) -> None:
    route = next(r for r in clips.router.routes if getattr(r, "path", "") == "/clips/{clip_id}")
    plain = create_app(Settings(data_dir=tmp_path / "a"))
    keyed = create_app(Settings(data_dir=tmp_path / "b", api_key="k3y-one"))
    for app in (plain, keyed):  # writes need the key in both: the route checks it itself
        assert any(r is route for r in app.router.routes)
    reads = create_app(
        Settings(data_dir=tmp_path / "c", api_key="k3y-one", require_key_for_reads=True)
    )
    assert not any(r is route for r in reads.router.routes)  # included with the key check
    with TestClient(reads) as client:
        assert client.get("/clips/1").status_code == 401
        assert client.get("/clips/1", headers={"X-API-Key": "k3y-one"}).status_code == 404
    with TestClient(plain) as client:
        assert client.get("/clips/1").status_code == 404
