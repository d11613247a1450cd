"""UI fixtures: the real app with the UI mounted (``mount_ui`` is idempotent, so these work
whether or not ``create_app`` already calls it), on the real motion core or the fake one."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from app.api.ui import mount_ui
from app.config import Settings
from app.main import create_app
from app.services.describe import Describer
from tests.services.fakes import FakeDescriber


def ui_app(settings: Settings, describer: Describer | None = None) -> FastAPI:
    app = create_app(settings, describer=describer)
    mount_ui(app)
    return app


@pytest.fixture
def ui_client(settings: Settings) -> Iterator[TestClient]:
    """The real app and motion core with the UI's routes."""
    with TestClient(ui_app(settings)) as client:
        yield client


@pytest.fixture
def fake_ui_client(settings: Settings) -> Iterator[TestClient]:
    """The UI's routes over the fake motion core (vectors chosen by the test)."""
    with TestClient(ui_app(settings, FakeDescriber())) as client:
        yield client


def upload_bvh(client: TestClient, path: Path, labels: list[str] | None = None) -> int:
    response = client.post(
        "/clips", files={"file": (path.name, path.read_bytes())}, data={"labels": labels or []}
    )
    assert response.status_code in (200, 201), response.text
    clip_id: int = response.json()["id"]
    return clip_id


def upload_asf_amc(client: TestClient, asf: Path, amc: Path) -> int:
    response = client.post(
        "/clips",
        files={"skeleton": (asf.name, asf.read_bytes()), "motion": (amc.name, amc.read_bytes())},
    )
    assert response.status_code in (200, 201), response.text
    clip_id: int = response.json()["id"]
    return clip_id
