"""API fixtures: a client on the fake motion core (exact, fast) and helpers to upload."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from tests.services.fakes import FakeDescriber


@pytest.fixture
def fake_client(settings: Settings) -> Iterator[TestClient]:
    """The real app and storage, with vectors chosen by the test (see tests/services/fakes.py)."""
    with TestClient(create_app(settings, describer=FakeDescriber())) as client:
        yield client
