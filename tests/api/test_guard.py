"""The guard's access table is shared by apps with the same routes (app/api/guard.py,
``shared_access_table``; app/main.py, ``access_table``): sound only if no setting changes a
level, and only for apps whose routes are the same."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter

from app.api.guard import Access, AccessTable
from app.config import Settings
from app.main import access_table, create_app

SETTINGS_THAT_CHANGE_THE_SCHEMA = [
    {},
    {"api_key": "k3y-one"},
    {"api_key": "k3y-one", "require_key_for_reads": True},
    {"api_key": "k3y-one", "require_key_for_heavy": True},
    {"cors_origins": "https://studio.example"},
]


def test_no_setting_changes_a_level(tmp_path: Path) -> None:
    tables = [
        AccessTable.of(create_app(Settings(data_dir=tmp_path / str(i), **changes)).openapi())
        for i, changes in enumerate(SETTINGS_THAT_CHANGE_THE_SCHEMA)
    ]
    assert all(table == tables[0] for table in tables[1:])
    # What the table holds is this app's operations, not an empty shell.
    assert tables[0].find("POST", "/clips")[1].level == Access.WRITE
    assert tables[0].find("DELETE", "/clips/7")[1].level == Access.WRITE
    assert tables[0].find("GET", "/clips/7/file")[1].heavy_with


def test_apps_with_the_same_routes_share_one_table(tmp_path: Path) -> None:
    first = create_app(Settings(data_dir=tmp_path / "a"))
    second = create_app(Settings(data_dir=tmp_path / "b", api_key="k3y-one"))
    assert access_table(first) is access_table(second)
    assert access_table(first) == AccessTable.of(second.openapi())


def test_a_route_added_after_create_app_gets_its_own_table(tmp_path: Path) -> None:
    plain = create_app(Settings(data_dir=tmp_path / "a"))
    grown = create_app(Settings(data_dir=tmp_path / "b"))
    extra = APIRouter()
    extra.add_api_route("/grown-here", lambda: {}, methods=["POST"])  # unsafe, no write role
    grown.include_router(extra)
    path, access = access_table(grown).find("POST", "/grown-here")
    assert path == "/grown-here" and access.level == Access.HEAVY
    assert access_table(plain).find("POST", "/grown-here")[0] == ""  # not one of its routes
