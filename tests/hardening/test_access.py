"""Access control (API keys), CORS, and safe names for stored and downloaded files."""

from __future__ import annotations

import hmac
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from app.api import auth
from app.api.clips import _attachment
from app.config import Settings
from app.main import create_app
from tests.services.fakes import FakeDescriber, fake_motion

KEY = "s3cret-key-Zq9"
OTHER_KEY = "second-key-7Hk"


def clip_file(n: int) -> tuple[str, bytes]:
    return (f"clip{n}.bvh", fake_motion([n, 0, 0]))


def configured(settings: Settings, **changes: Any) -> Settings:
    """``settings`` with ``changes``, validated (``model_copy`` would not validate them)."""
    return Settings(data_dir=settings.data_dir, **changes)


def client_for(settings: Settings) -> TestClient:
    return TestClient(create_app(settings, describer=FakeDescriber()))


@pytest.fixture
def keyed(settings: Settings) -> Iterator[TestClient]:
    with client_for(configured(settings, api_key=f"{KEY}, {OTHER_KEY}")) as client:
        yield client


def assert_error(response: Any, status: int, code: str) -> dict[str, str]:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error", "detail"} and body["error"] == code
    return body


# -- API keys -------------------------------------------------------------------------------


def test_without_a_key_everything_is_open_and_the_start_up_log_says_so(
    settings: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    with client_for(settings) as client:
        created = client.post("/clips", files={"file": clip_file(1)})
        assert created.status_code == 201
        clip_id = created.json()["id"]
        assert client.patch(f"/clips/{clip_id}", json={"name": "x"}).status_code == 200
        assert client.delete(f"/clips/{clip_id}").status_code == 204
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert any(
        "no API key configured: anyone can change the library" in r.message for r in warnings
    )


def test_writes_need_a_key_reads_do_not(keyed: TestClient) -> None:
    files = {"file": clip_file(1)}
    body = assert_error(keyed.post("/clips", files=files), 401, "unauthorized")
    assert "Authorization: Bearer" in body["detail"] and "X-API-Key" in body["detail"]
    assert keyed.post("/clips", files=files).headers["www-authenticate"] == "Bearer"
    for headers in (
        {"Authorization": "Bearer wrong"},
        {"X-API-Key": "wrong"},
        {"Authorization": f"Bearer {KEY}x"},
        {"X-API-Key": KEY[:-1]},
    ):
        assert_error(keyed.post("/clips", files=files, headers=headers), 403, "forbidden")
    assert_error(
        keyed.post("/clips", files=files, headers={"Authorization": f"Basic {KEY}"}),
        401,
        "unauthorized",
    )
    assert keyed.get("/clips").json()["total"] == 0, "refused uploads stored nothing"

    created = keyed.post("/clips", files=files, headers={"Authorization": f"Bearer {KEY}"})
    assert created.status_code == 201
    clip_id = created.json()["id"]
    # either header, any configured key, scheme in any case
    second = keyed.post(
        "/clips", files={"file": clip_file(2)}, headers={"authorization": f"bearer {OTHER_KEY}"}
    )
    assert second.status_code == 201

    assert_error(keyed.patch(f"/clips/{clip_id}", json={"name": "y"}), 401, "unauthorized")
    assert_error(
        keyed.patch(f"/clips/{clip_id}", json={"name": "y"}, headers={"X-API-Key": "no"}),
        403,
        "forbidden",
    )
    renamed = keyed.patch(f"/clips/{clip_id}", json={"name": "y"}, headers={"X-API-Key": KEY})
    assert renamed.status_code == 200 and renamed.json()["name"] == "y"

    assert_error(keyed.delete(f"/clips/{clip_id}"), 401, "unauthorized")
    assert_error(
        keyed.delete(f"/clips/{clip_id}", headers={"X-API-Key": OTHER_KEY + "!"}), 403, "forbidden"
    )
    # reading stays open
    assert keyed.get(f"/clips/{clip_id}").status_code == 200
    assert keyed.get(f"/clips/{clip_id}/file").status_code == 200
    assert keyed.get("/search", params={"clip": clip_id}).status_code == 200
    assert keyed.post("/search", files={"file": clip_file(3)}).status_code == 200
    assert keyed.get("/descriptors").status_code == 200
    assert keyed.delete(f"/clips/{clip_id}", headers={"X-API-Key": OTHER_KEY}).status_code == 204


def test_reads_can_need_a_key_too(settings: Settings) -> None:
    locked = configured(settings, api_key=KEY, require_key_for_reads=True)
    with client_for(locked) as client:
        for url in ("/clips", "/descriptors", "/search?clip=1", "/clips/1", "/clips/1/file"):
            assert_error(client.get(url), 401, "unauthorized")
            assert_error(client.get(url, headers={"X-API-Key": "nope"}), 403, "forbidden")
        assert_error(client.post("/search", files={"file": clip_file(1)}), 401, "unauthorized")
        assert client.get("/clips", headers={"X-API-Key": KEY}).status_code == 200
        assert (
            client.get("/descriptors", headers={"Authorization": f"Bearer {KEY}"}).status_code
            == 200
        )
        # health checks and the docs stay open
        assert client.get("/health").status_code == 200
        assert client.get("/openapi.json").status_code == 200
        assert client.get("/docs").status_code == 200


def test_reads_needing_a_key_without_a_key_is_a_configuration_error() -> None:
    with pytest.raises(ValidationError, match="MOCAP_API_KEY"):
        Settings(require_key_for_reads=True)


def test_keys_are_compared_in_constant_time_against_every_key(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[tuple[bytes, bytes]] = []
    compare = hmac.compare_digest

    def counting(a: bytes, b: bytes) -> bool:
        calls.append((a, b))
        return compare(a, b)

    monkeypatch.setattr(auth.hmac, "compare_digest", counting)
    configured = (b"first", b"second", b"third")
    assert auth.key_is_valid(b"first", configured)  # a match on the first key ...
    assert len(calls) == 3  # ... still compares against every key
    assert not auth.key_is_valid(b"fourth", configured)
    assert auth.key_is_valid("ключ".encode(), ("ключ".encode(),))


def test_keys_never_appear_in_logs_or_errors(
    settings: Settings, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    with client_for(configured(settings, api_key=KEY)) as client:
        replies = [
            client.post("/clips", files={"file": clip_file(1)}, headers={"X-API-Key": KEY}),
            client.post("/clips", files={"file": clip_file(2)}, headers={"X-API-Key": KEY + "x"}),
            client.post("/clips", files={"file": clip_file(3)}, headers={"Authorization": KEY}),
        ]
    assert [r.status_code for r in replies] == [201, 403, 401]
    for reply in replies:
        assert KEY not in reply.text
    assert KEY not in caplog.text
    assert KEY not in repr(configured(settings, api_key=KEY))
    assert KEY not in str(configured(settings, api_key=KEY).model_dump())


def test_openapi_declares_the_security_scheme_on_the_write_routes(keyed: TestClient) -> None:
    schema = keyed.get("/openapi.json").json()
    schemes = schema["components"]["securitySchemes"]
    assert schemes["BearerKey"] == {
        "type": "http",
        "scheme": "bearer",
        "description": schemes["BearerKey"]["description"],
    }
    assert schemes["ApiKeyHeader"]["type"] == "apiKey"
    assert schemes["ApiKeyHeader"]["in"] == "header"
    assert schemes["ApiKeyHeader"]["name"] == "X-API-Key"
    writes = [("/clips", "post"), ("/clips/{clip_id}", "patch"), ("/clips/{clip_id}", "delete")]
    for path, method in writes:
        operation = schema["paths"][path][method]
        assert {"BearerKey": []} in operation["security"], (path, method)
        assert {"ApiKeyHeader": []} in operation["security"], (path, method)
        assert {"401", "403"} <= set(operation["responses"]), (path, method)
    for path, method in [("/clips", "get"), ("/search", "get"), ("/health", "get")]:
        assert "security" not in schema["paths"][path][method], (path, method)


def test_openapi_declares_security_on_reads_when_they_need_a_key(settings: Settings) -> None:
    locked = configured(settings, api_key=KEY, require_key_for_reads=True)
    with client_for(locked) as client:
        schema = client.get("/openapi.json").json()
    for path, method in [("/clips", "get"), ("/search", "get"), ("/search", "post")]:
        operation = schema["paths"][path][method]
        assert operation["security"], (path, method)
        assert {"401", "403"} <= set(operation["responses"]), (path, method)
    assert "security" not in schema["paths"]["/health"]["get"]


# -- CORS -----------------------------------------------------------------------------------


def test_cors_is_off_by_default(settings: Settings) -> None:
    with client_for(settings) as client:
        response = client.get("/health", headers={"Origin": "https://evil.example"})
        assert response.status_code == 200
        assert not any(h.lower().startswith("access-control-") for h in response.headers)
        preflight = client.options(
            "/clips",
            headers={"Origin": "https://evil.example", "Access-Control-Request-Method": "POST"},
        )
        assert "access-control-allow-origin" not in preflight.headers


def test_cors_allows_only_the_configured_origins(settings: Settings) -> None:
    studio = "https://studio.example"
    with client_for(configured(settings, cors_origins=[studio])) as client:
        ok = client.get("/health", headers={"Origin": studio})
        assert ok.headers["access-control-allow-origin"] == studio
        other = client.get("/health", headers={"Origin": "https://evil.example"})
        assert "access-control-allow-origin" not in other.headers
        preflight = client.options(
            "/clips",
            headers={
                "Origin": studio,
                "Access-Control-Request-Method": "POST",
                "Access-Control-Request-Headers": "authorization, x-api-key",
            },
        )
        assert preflight.status_code == 200
        assert preflight.headers["access-control-allow-origin"] == studio
        allowed = preflight.headers["access-control-allow-headers"].lower()
        assert "authorization" in allowed and "x-api-key" in allowed


def test_cors_origins_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOCAP_CORS_ORIGINS", "https://a.example, https://b.example")
    assert Settings().cors_origins == ["https://a.example", "https://b.example"]
    monkeypatch.setenv("MOCAP_CORS_ORIGINS", '["https://c.example"]')
    assert Settings().cors_origins == ["https://c.example"]
    monkeypatch.setenv("MOCAP_CORS_ORIGINS", "")
    assert Settings().cors_origins == []


# -- file names -----------------------------------------------------------------------------

HOSTILE_NAMES = [
    'wa"lk.bvh',
    "walk\r\nSet-Cookie: a=b.bvh",
    "wa\\lk.bvh",
    "ходьба 走る.bvh",
    "x; filename=evil.sh",
    "%22%0d%0a.bvh",
    "\x00\x01\x7f.bvh",
    "",
]


@pytest.mark.parametrize("name", HOSTILE_NAMES)
def test_content_disposition_is_safe_for_any_name(name: str) -> None:
    header = _attachment(name)
    assert header.isascii() and header.isprintable()
    plain = header.split('filename="', 1)[1].split('"', 1)[0]
    assert not set(plain) & set('"\\\r\n;%')
    exact = header.split("filename*=UTF-8''", 1)[1]
    assert ";" not in exact and " " not in exact and '"' not in exact
    assert unquote(exact) == name
    assert header.count(";") == 2  # attachment; filename=...; filename*=...


def raw_upload(filename: bytes, data: bytes) -> tuple[bytes, str]:
    """A multipart body written by hand, so the file name reaches the server unescaped."""
    body = (
        b'--b0undary\r\nContent-Disposition: form-data; name="file"; filename="'
        + filename
        + b'"\r\nContent-Type: application/octet-stream\r\n\r\n'
        + data
        + b"\r\n--b0undary--\r\n"
    )
    return body, "multipart/form-data; boundary=b0undary"


def test_uploaded_names_never_become_paths(settings: Settings) -> None:
    names = [
        b"../../../../etc/passwd.bvh",
        b"..\\..\\windows\\win.ini.bvh",
        b"/abs/olute.bvh",
        b"ctl\x01\x1b[31mred.bvh",
        "ходьба.bvh".encode(),
    ]
    with client_for(settings) as client:
        for n, name in enumerate(names):
            body, content_type = raw_upload(name, fake_motion([n, 1, 1]))
            response = client.post("/clips", content=body, headers={"content-type": content_type})
            assert response.status_code == 201, (name, response.text)
            stored = response.json()["filenames"][0]
            assert "/" not in stored and "\\" not in stored and stored.isprintable(), stored
            download = client.get(f"/clips/{response.json()['id']}/file")
            assert download.status_code == 200
            disposition = download.headers["content-disposition"]
            assert disposition.isascii() and "\r" not in disposition and "\n" not in disposition
            assert unquote(disposition.split("filename*=UTF-8''")[1]) == stored
        stored_names = [c["filenames"][0] for c in client.get("/clips").json()["items"]]
    assert stored_names == [
        "passwd.bvh",
        "win.ini.bvh",
        "olute.bvh",
        "ctl__[31mred.bvh",
        "ходьба.bvh",
    ]
    # every stored file is named by its content hash, inside files/
    data_dir = settings.data_dir
    stored_files = [p for p in data_dir.rglob("*") if p.is_file()]
    for path in stored_files:
        relative = path.relative_to(data_dir)
        assert relative.parts[0] in ("files", "indexes") or relative.name.startswith(
            "mocap-index.sqlite3"
        ), relative
        if relative.parts[0] == "files":
            assert len(relative.name) == 64 and relative.parts[1] == relative.name[:2]
    assert not (Path("/etc/passwd.bvh")).exists()
