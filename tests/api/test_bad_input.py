"""Input no database can take answers 422 naming the parameter, the same on SQLite and
PostgreSQL: ids past 64 bits, NUL characters and lone surrogates in any text a user gives."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.services.fakes import fake_motion

PAST_64_BITS = str(2**64 + 1)


def assert_invalid(response: Any, field: str) -> None:
    assert response.status_code == 422, response.text
    body = response.json()
    assert body["error"] == "invalid_input", body
    assert body["detail"].startswith(field) or f".{field}:" in body["detail"], body


@pytest.mark.parametrize("clip", [PAST_64_BITS, f"-{PAST_64_BITS}", "0"])
@pytest.mark.parametrize("path", ["/search", "/search/moments"])
def test_a_query_clip_id_outside_the_database_keys_is_invalid(
    fake_client: TestClient, path: str, clip: str
) -> None:
    assert_invalid(fake_client.get(path, params={"clip": clip}), "clip")


def test_a_nul_character_is_refused_naming_the_field(fake_client: TestClient) -> None:
    text = "walk\x00ing"
    stored = fake_client.post("/clips", files={"file": ("a.bvh", fake_motion([1, 0, 0]))})
    assert stored.status_code == 201, stored.text
    clip = stored.json()
    for field in ("name", "labels", "source", "licence"):
        data = {field: text}
        upload = fake_client.post(
            "/clips", files={"file": ("b.bvh", fake_motion([2, 0, 0]))}, data=data
        )
        assert_invalid(upload, field)
        search = fake_client.post(
            "/search", files={"file": ("b.bvh", fake_motion([2, 0, 0]))}, data=data
        )
        assert_invalid(search, field)
        value: Any = [text] if field == "labels" else text
        assert_invalid(fake_client.patch(f"/clips/{clip['id']}", json={field: value}), field)
    for url, params in [
        ("/clips", {"label": text}),
        ("/library/clips", {"label": text}),
        ("/library/clips", {"q": text}),
        ("/search", {"clip": clip["id"], "label": text}),
    ]:
        assert_invalid(fake_client.get(url, params=params), "label" if "label" in params else "q")
    # nothing stored, nothing changed
    assert fake_client.get("/clips").json()["total"] == 1
    assert fake_client.get(f"/clips/{clip['id']}").json() == clip


@pytest.mark.parametrize("field", ["name", "labels", "source", "licence"])
def test_a_lone_surrogate_is_refused_naming_the_field(fake_client: TestClient, field: str) -> None:
    """JSON can escape half of a surrogate pair (``\\ud800``); no UTF-8 exists for it."""
    clip = fake_client.post("/clips", files={"file": ("a.bvh", fake_motion([1, 0, 0]))}).json()
    value = '["walk\\ud800"]' if field == "labels" else '"walk\\udfff"'
    answer = fake_client.patch(
        f"/clips/{clip['id']}",
        content=f'{{"{field}": {value}}}',
        headers={"content-type": "application/json"},
    )
    assert_invalid(answer, field)
    assert fake_client.get(f"/clips/{clip['id']}").json() == clip
