"""The page at /, its static files, and the library list's name/label filters."""

from __future__ import annotations

import re
from pathlib import Path

from fastapi.testclient import TestClient
from pydantic import SecretStr

from app.api.ui import STATIC_DIR, mount_ui
from app.config import Settings
from tests.services.fakes import FakeDescriber, fake_motion
from tests.ui.conftest import ui_app


def add(client: TestClient, name: str, labels: list[str]) -> int:
    response = client.post(
        "/clips", files={"file": (f"{name}.bvh", fake_motion(name=name))}, data={"labels": labels}
    )
    assert response.status_code == 201, response.text
    clip_id: int = response.json()["id"]
    return clip_id


def test_root_serves_the_page_and_its_modules(fake_ui_client: TestClient) -> None:
    response = fake_ui_client.get("/")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/html")
    csp = response.headers["content-security-policy"]
    assert "default-src 'self'" in csp and "script-src 'self'" in csp
    page = response.text
    assert '<script type="module" src="/static/app.js"' in page
    assert 'href="/static/style.css"' in page
    # Every file the page or a module imports is served, as JavaScript / CSS.
    app_js = fake_ui_client.get("/static/app.js")
    assert app_js.status_code == 200
    assert "javascript" in app_js.headers["content-type"]
    assert "text/css" in fake_ui_client.get("/static/style.css").headers["content-type"]
    for path in sorted(STATIC_DIR.glob("*.js")):
        imports = re.findall(r"from\s+\"\./([\w./-]+)\"", path.read_text())
        for name in imports:
            assert (STATIC_DIR / name).is_file(), f"{path.name} imports missing {name}"
            assert fake_ui_client.get(f"/static/{name}").status_code == 200
    # No file of the UI loads anything from another host.
    for path in STATIC_DIR.rglob("*"):
        if path.suffix in {".html", ".js", ".css"}:
            assert not re.search(r"(?:src|href|import)[^\n]*https?://", path.read_text()), path


def test_mount_ui_twice_adds_nothing(fake_ui_client: TestClient) -> None:
    app = fake_ui_client.app
    before = len(app.router.routes)  # type: ignore[attr-defined]
    mount_ui(app)  # type: ignore[arg-type]
    assert len(app.router.routes) == before  # type: ignore[attr-defined]


def test_the_ui_routes_are_documented(fake_ui_client: TestClient) -> None:
    paths = fake_ui_client.get("/openapi.json").json()["paths"]
    for path in ("/clips/{clip_id}/skeleton", "/skeleton", "/map", "/library/clips"):
        assert path in paths
    assert "/" not in paths


def test_find_clips_by_name_and_label(fake_ui_client: TestClient) -> None:
    ids = {
        name: add(fake_ui_client, name, labels)
        for name, labels in [
            ("Walk_happy", ["walk", "happy"]),
            ("walk_sad", ["walk"]),
            ("run_100%", ["run"]),
            ("run_fast", ["run", "happy"]),
            ("bow", []),
        ]
    }

    def names(**params: object) -> list[str]:
        response = fake_ui_client.get("/library/clips", params=params)
        assert response.status_code == 200, response.text
        return [c["name"] for c in response.json()["items"]]

    assert names(q="WALK") == ["Walk_happy", "walk_sad"]
    assert names(q="100%") == ["run_100%"]  # % and _ are no wildcards
    assert names(q="k_") == ["Walk_happy", "walk_sad"]
    assert names(q="_") == ["Walk_happy", "walk_sad", "run_100%", "run_fast"]
    assert names(label="happy") == ["Walk_happy", "run_fast"]
    assert names(q="run", label="happy") == ["run_fast"]
    assert names(q="  ") == list(ids)  # blank: no filter
    page = fake_ui_client.get("/library/clips", params={"limit": 2, "offset": 1}).json()
    assert page["total"] == 5 and [c["id"] for c in page["items"]] == [
        ids["walk_sad"],
        ids["run_100%"],
    ]
    item = page["items"][0]
    assert item["labels"] == ["walk"] and item["format"] == "bvh" and "duration" in item
    bad = fake_ui_client.get("/library/clips", params={"limit": 0})
    assert bad.status_code == 422 and bad.json()["detail"].startswith("limit:")
    bad = fake_ui_client.get("/library/clips", params={"offset": -1})
    assert bad.status_code == 422 and bad.json()["detail"].startswith("offset:")
    labels = fake_ui_client.get("/library/labels").json()
    assert labels == [
        {"label": "happy", "count": 2},
        {"label": "run", "count": 2},
        {"label": "walk", "count": 2},
    ]


def test_licences_in_use_are_counted_as_the_filters_compare_them(
    fake_ui_client: TestClient,
) -> None:
    for name, licence in [
        ("a", "CC0"),
        ("b", " cc0 "),
        ("c", "CC BY-NC 4.0"),
        ("d", ""),
        ("e", None),
        ("f", "CC0"),
    ]:
        data = {} if licence is None else {"licence": licence}
        response = fake_ui_client.post(
            "/clips", files={"file": (f"{name}.bvh", fake_motion(name=name))}, data=data
        )
        assert response.status_code == 201, response.text
    rows = fake_ui_client.get("/library/licences").json()
    # One row per licence (trimmed, any case), most used first; no licence is not a licence.
    assert [(r["licence"].lower(), r["count"]) for r in rows] == [("cc0", 3), ("cc by-nc 4.0", 1)]
    # Each value offered filters to exactly its count.
    for row in rows:
        page = fake_ui_client.get("/clips", params={"licence": row["licence"]}).json()
        assert page["total"] == row["count"]


def test_data_routes_need_the_key_when_reads_do(tmp_path: Path) -> None:
    settings = Settings(
        data_dir=tmp_path / "data", api_key=SecretStr("s3cret"), require_key_for_reads=True
    )
    with TestClient(ui_app(settings, FakeDescriber())) as client:
        # The page and its files are open, like /docs: the page asks for the key.
        assert client.get("/").status_code == 200
        assert client.get("/static/app.js").status_code == 200
        for path in (
            "/map",
            "/library/clips",
            "/library/labels",
            "/library/licences",
            "/clips/1/skeleton",
        ):
            response = client.get(path)
            assert response.status_code == 401, path
            assert response.json()["error"] == "unauthorized"
            assert client.get(path, headers={"X-API-Key": "wrong"}).status_code == 403
        key = {"X-API-Key": "s3cret"}
        assert client.get("/map", headers=key).status_code == 200
        assert client.get("/library/labels", headers=key).json() == []
        response = client.post("/skeleton", files={"file": ("a.bvh", b"x")})
        assert response.status_code == 401
        assert client.get("/clips/1/skeleton", headers=key).status_code == 404


def test_data_routes_are_open_without_a_read_key(tmp_path: Path) -> None:
    settings = Settings(data_dir=tmp_path / "data", api_key=SecretStr("s3cret"))
    with TestClient(ui_app(settings, FakeDescriber())) as client:
        assert client.get("/map").status_code == 200
        assert client.get("/library/clips").status_code == 200
