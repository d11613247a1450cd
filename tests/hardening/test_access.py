"""Access control (API keys, heavy routes, Host and Origin checks), CORS, and safe names for
stored and downloaded files. What must happen before a request's body is read is tested on a
live server, over sockets written by hand."""

from __future__ import annotations

import hmac
import logging
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import httpx
import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError

from app.api import auth
from app.api.clips import _attachment
from app.config import Settings
from app.main import create_app
from tests.hardening.live import LiveServer, raw_request, unique_upload
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
        assert {"BearerKey": ["write"]} in operation["security"], (path, method)
        assert {"ApiKeyHeader": ["write"]} in operation["security"], (path, method)
        assert {"401", "403"} <= set(operation["responses"]), (path, method)
    for path, method in [("/clips", "get"), ("/search", "get"), ("/health", "get")]:
        assert "security" not in schema["paths"][path][method], (path, method)


def test_openapi_declares_security_on_reads_when_they_need_a_key(settings: Settings) -> None:
    locked = configured(settings, api_key=KEY, require_key_for_reads=True)
    with client_for(locked) as client:
        schema = client.get("/openapi.json").json()
    for path, method in [("/clips", "get"), ("/search", "get"), ("/search", "post")]:
        operation = schema["paths"][path][method]
        assert {"ApiKeyHeader": ["read"]} in operation["security"], (path, method)
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


# -- one rule for keys: one valid key is enough, a wrong key is never overridden ------------

BASIC = "Basic dXNlcjpwYXNzd29yZA=="  # user:password, as a proxy in front might add
KEY_COMBINATIONS: list[tuple[str, list[tuple[str, str]], int]] = [
    ("nothing", [], 401),
    ("bearer", [("Authorization", f"Bearer {KEY}")], 201),
    ("header", [("X-API-Key", KEY)], 201),
    ("bearer in lower case", [("authorization", f"bearer {OTHER_KEY}")], 201),
    ("basic beside a valid header", [("Authorization", BASIC), ("X-API-Key", KEY)], 201),
    ("digest beside a valid header", [("Authorization", "Digest u=1"), ("X-API-Key", KEY)], 201),
    ("basic alone", [("Authorization", BASIC)], 401),
    ("a key without a scheme", [("Authorization", KEY)], 401),
    ("blank bearer beside a valid header", [("Authorization", "Bearer "), ("X-API-Key", KEY)], 201),
    ("blank header", [("X-API-Key", "  ")], 401),
    ("two valid keys", [("Authorization", f"Bearer {KEY}"), ("X-API-Key", OTHER_KEY)], 201),
    ("wrong bearer", [("Authorization", "Bearer wrong")], 403),
    ("wrong header", [("X-API-Key", "wrong")], 403),
    (
        "wrong bearer beside a valid header",
        [("Authorization", "Bearer no"), ("X-API-Key", KEY)],
        403,
    ),
    (
        "valid bearer beside a wrong header",
        [("Authorization", f"Bearer {KEY}"), ("X-API-Key", "no")],
        403,
    ),
    ("two headers, one wrong", [("X-API-Key", KEY), ("X-API-Key", "wrong")], 403),
]


@pytest.mark.parametrize(
    ("headers", "status"),
    [(h, s) for _name, h, s in KEY_COMBINATIONS],
    ids=[name for name, _h, _s in KEY_COMBINATIONS],
)
def test_every_combination_of_key_headers(
    keyed: TestClient, headers: list[tuple[str, str]], status: int
) -> None:
    """A valid key in either place is enough; a present but wrong key is refused even beside
    a valid one; an Authorization header of another scheme (a proxy's Basic) is no key."""
    valid = {"X-API-Key": KEY}
    clip_id = keyed.post("/clips", files={"file": clip_file(0)}, headers=valid).json()["id"]
    answers = {
        "upload": keyed.post("/clips", files={"file": clip_file(1)}, headers=headers),
        "rename": keyed.patch(f"/clips/{clip_id}", json={"name": "new"}, headers=headers),
        "delete": keyed.delete(f"/clips/{clip_id}", headers=headers),
    }
    expected = {"upload": status, "rename": 200, "delete": 204} if status == 201 else None
    for action, answer in answers.items():
        if expected is not None:
            assert answer.status_code == expected[action], (action, answer.text)
            continue
        code = "unauthorized" if status == 401 else "forbidden"
        body = assert_error(answer, status, code)
        if status == 403 and len(headers) > 1:
            assert "never overridden" in body["detail"], body
    names = [clip["name"] for clip in keyed.get("/clips").json()["items"]]
    assert names == (["clip1"] if status == 201 else ["clip0"]), "a refused request changes nothing"


# -- keys and body sizes are checked before the body is read (live server) -------------------

FIFTY_MB = 50 * 1024 * 1024


@pytest.fixture(scope="module")
def keyed_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    data_dir = tmp_path_factory.mktemp("access") / "data"
    env = {"MOCAP_API_KEY": KEY, "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "2"}
    with LiveServer(data_dir, env) as server:
        with httpx.Client(base_url=server.url, headers={"X-API-Key": KEY}, timeout=30) as client:
            assert client.post("/clips", files=unique_upload(0)).status_code == 201
        yield server
    assert KEY not in server.log()


def head(
    server: LiveServer, request_line: str, content_type: str, length: int, *extra: str
) -> bytes:
    lines = [
        request_line,
        f"Host: 127.0.0.1:{server.port}",
        f"Content-Type: {content_type}",
        f"Content-Length: {length}",
        *extra,
    ]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


MULTIPART = "multipart/form-data; boundary=xx"
FIRST_PART = b'--xx\r\nContent-Disposition: form-data; name="file"; filename="a.bvh"\r\n\r\nHIER'


def test_an_anonymous_50_mb_upload_is_refused_before_its_body(keyed_server: LiveServer) -> None:
    """The client sends the head and the first bytes, then stalls: the answer comes anyway."""
    upload = head(keyed_server, "POST /clips HTTP/1.1", MULTIPART, FIFTY_MB)
    answer = raw_request(keyed_server, upload, [FIRST_PART])
    assert answer.startswith(b"HTTP/1.1 401"), answer[:300]
    assert b'"unauthorized"' in answer
    wrong = head(keyed_server, "POST /clips HTTP/1.1", MULTIPART, FIFTY_MB, "X-API-Key: nope")
    answer = raw_request(keyed_server, wrong, [FIRST_PART])
    assert answer.startswith(b"HTTP/1.1 403"), answer[:300]
    # With the key the server waits for the body it was promised: the key decided.
    keyed = head(keyed_server, "POST /clips HTTP/1.1", MULTIPART, FIFTY_MB, f"X-API-Key: {KEY}")
    assert raw_request(keyed_server, keyed, [FIRST_PART], timeout=1.0) == b""


def test_an_anonymous_50_mb_json_patch_is_refused_before_its_body(keyed_server: LiveServer) -> None:
    patch = head(keyed_server, "PATCH /clips/1 HTTP/1.1", "application/json", FIFTY_MB)
    answer = raw_request(keyed_server, patch, [b'{"name": "'])
    assert answer.startswith(b"HTTP/1.1 401"), answer[:300]


def test_a_keyed_json_body_is_capped_before_it_is_parsed(keyed_server: LiveServer) -> None:
    """Parsed JSON takes ~13x its size: a JSON route takes at most 1 MiB, from the declared
    length before the body, or as a chunked body streams in."""
    declared = head(
        keyed_server, "PATCH /clips/1 HTTP/1.1", "application/json", FIFTY_MB, f"X-API-Key: {KEY}"
    )
    answer = raw_request(keyed_server, declared, [b'{"name": "'])
    assert answer.startswith(b"HTTP/1.1 413"), answer[:300]
    assert b"JSON body over the 1048576-byte limit" in answer
    chunked = (
        "PATCH /clips/1 HTTP/1.1\r\n"
        f"Host: 127.0.0.1:{keyed_server.port}\r\nContent-Type: application/json\r\n"
        f"X-API-Key: {KEY}\r\nTransfer-Encoding: chunked\r\n\r\n"
    ).encode()
    piece = b'"' + b"x" * 65534 + b'",'
    chunks = [b"1\r\n[\r\n"] + [b"%x\r\n%s\r\n" % (len(piece), piece)] * 40  # 2.6 MB
    answer = raw_request(keyed_server, chunked, chunks)
    assert answer.startswith(b"HTTP/1.1 413"), answer[:300]
    with httpx.Client(base_url=keyed_server.url, timeout=30) as client:
        assert client.get("/clips/1").json()["name"] != "x"


# -- heavy requests per client, and keys for heavy routes ------------------------------------


def held_heavy_request(server: LiveServer, path: str = "/search") -> socket.socket:
    """A POST whose body never comes: it stays in progress until the socket closes."""
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=10)
    sock.sendall(head(server, f"POST {path} HTTP/1.1", MULTIPART, 100_000) + FIRST_PART)
    return sock


def test_anonymous_heavy_requests_are_limited_per_client(keyed_server: LiveServer) -> None:
    with httpx.Client(base_url=keyed_server.url, timeout=30) as client:
        held = [held_heavy_request(keyed_server) for _ in range(2)]
        try:
            time.sleep(0.3)  # both heads reach the server (the answer below says if not)
            third = client.post("/search", files=unique_upload(1))
            assert_error(third, 429, "too_many_requests")
            assert third.headers["retry-after"] == "1"
            assert "MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT" in third.json()["detail"]
            assert_error(client.get("/map"), 429, "too_many_requests")
            assert_error(client.get("/clips/1/file?format=bvh"), 429, "too_many_requests")
            # light reads go on; a client with a valid key is not limited per client
            assert client.get("/clips/1/file").status_code == 200
            assert client.get("/search", params={"clip": 1}).status_code == 200
            keyed = client.post("/search", files=unique_upload(1), headers={"X-API-Key": KEY})
            assert keyed.status_code == 200, keyed.text
        finally:
            for sock in held:
                sock.close()
        deadline = time.monotonic() + 10  # the server sees the disconnects and frees the slots
        while client.post("/search", files=unique_upload(1)).status_code == 429:
            assert time.monotonic() < deadline, "slots not given back after the clients left"
            time.sleep(0.1)


def test_uploads_to_an_open_server_are_limited_per_client(tmp_path: Path) -> None:
    """Without any key configured every client is anonymous: its uploads count too."""
    env = {"MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT": "2"}
    with (
        LiveServer(tmp_path / "data", env) as server,
        httpx.Client(base_url=server.url, timeout=30) as client,
    ):
        held = [held_heavy_request(server, "/clips") for _ in range(2)]
        try:
            time.sleep(0.3)
            assert_error(client.post("/clips", files=unique_upload(1)), 429, "too_many_requests")
            assert client.get("/clips").status_code == 200
        finally:
            for sock in held:
                sock.close()
        deadline = time.monotonic() + 10
        while (answer := client.post("/clips", files=unique_upload(1))).status_code == 429:
            assert time.monotonic() < deadline, "slots not given back after the clients left"
            time.sleep(0.1)
        assert answer.status_code == 201, answer.text


HEAVY_REQUESTS = [
    ("POST", "/search", True),
    ("POST", "/search/moments", True),
    ("POST", "/skeleton", True),
    ("GET", "/map", False),
    ("GET", "/search/moments?clip=1", False),
    ("GET", "/clips/1/file?format=bvh", False),
    ("GET", "/clips/1/file?start=0&end=0.1", False),
]
LIGHT_READS = ["/clips", "/clips/1", "/clips/1/file", "/search?clip=1", "/descriptors", "/health"]


def test_heavy_routes_can_need_a_key(settings: Settings) -> None:
    locked = configured(settings, api_key=KEY, require_key_for_heavy=True)
    with client_for(locked) as client:
        created = client.post("/clips", files={"file": clip_file(1)}, headers={"X-API-Key": KEY})
        assert created.status_code == 201 and created.json()["id"] == 1
        for method, url, upload in HEAVY_REQUESTS:
            files = {"file": clip_file(2)} if upload else None
            body = assert_error(client.request(method, url, files=files), 401, "unauthorized")
            assert "MOCAP_REQUIRE_KEY_FOR_HEAVY" in body["detail"]
            wrong = client.request(method, url, files=files, headers={"X-API-Key": "no"})
            assert_error(wrong, 403, "forbidden")
            keyed = client.request(method, url, files=files, headers={"X-API-Key": KEY})
            assert keyed.status_code not in (401, 403, 429), (url, keyed.text)
        for url in LIGHT_READS:
            assert client.get(url).status_code == 200, url
        assert_error(client.post("/clips", files={"file": clip_file(3)}), 401, "unauthorized")
        schema = client.get("/openapi.json").json()
    for method, url, _upload in HEAVY_REQUESTS:
        path = {"/clips/1/file": "/clips/{clip_id}/file"}.get(url.split("?")[0], url.split("?")[0])
        operation = schema["paths"][path][method.lower()]
        assert {"ApiKeyHeader": ["heavy"]} in operation["security"], (method, path)
        assert {"401", "403", "429"} <= set(operation["responses"]), (method, path)
    # a plain download needs no key: the requirement is optional there
    assert {} in schema["paths"]["/clips/{clip_id}/file"]["get"]["security"]
    assert "security" not in schema["paths"]["/clips/{clip_id}"]["get"]


def test_heavy_routes_needing_a_key_without_a_key_is_a_configuration_error() -> None:
    with pytest.raises(ValidationError, match="MOCAP_API_KEY"):
        Settings(require_key_for_heavy=True)


# -- cross-site requests and DNS rebinding ---------------------------------------------------

CROSS_SITE = [
    {"Origin": "https://evil.example"},
    {"Origin": "https://evil.example", "Sec-Fetch-Site": "cross-site"},
    {"Origin": "null"},  # a sandboxed frame or a data: page
    {"Origin": "http://testserver:8080"},  # another port of the same host: another origin
    {"Sec-Fetch-Site": "cross-site"},
    {"Sec-Fetch-Site": "same-site"},
]
SAME_SITE = [
    {},  # not a browser
    {"Origin": "http://testserver", "Sec-Fetch-Site": "same-origin"},  # the web UI
    {"Origin": "http://TestServer:80"},
    {"Sec-Fetch-Site": "none"},  # typed by the user
]


def test_cross_site_writes_are_refused(settings: Settings) -> None:
    with client_for(settings) as client:
        stored = client.post("/clips", files={"file": clip_file(0)}).json()["id"]
        for n, headers in enumerate(CROSS_SITE, start=1):
            for answer in (
                client.post("/clips", files={"file": clip_file(n)}, headers=headers),
                client.post("/search", files={"file": clip_file(n)}, headers=headers),
                client.patch(f"/clips/{stored}", json={"name": "pwned"}, headers=headers),
                client.delete(f"/clips/{stored}", headers=headers),
                client.delete("/clips?label=x&confirm=true", headers=headers),
            ):
                body = assert_error(answer, 403, "cross_site_request")
                assert "MOCAP_CORS_ORIGINS" in body["detail"] or "Sec-Fetch-Site" in body["detail"]
            # reading stays possible (the browser keeps the answer from the page without CORS)
            assert client.get(f"/clips/{stored}", headers=headers).status_code == 200
        clips = client.get("/clips").json()
        assert clips["total"] == 1 and clips["items"][0]["name"] == "clip0"
        for n, headers in enumerate(SAME_SITE, start=10):
            created = client.post("/clips", files={"file": clip_file(n)}, headers=headers)
            assert created.status_code == 201, (headers, created.text)
            renamed = client.patch(f"/clips/{stored}", json={"name": f"n{n}"}, headers=headers)
            assert renamed.status_code == 200, (headers, renamed.text)


def test_cross_site_writes_from_a_configured_origin_are_allowed(settings: Settings) -> None:
    studio = "https://studio.example"
    with client_for(configured(settings, cors_origins=[studio])) as client:
        allowed = client.post("/clips", files={"file": clip_file(1)}, headers={"Origin": studio})
        assert allowed.status_code == 201
        assert allowed.headers["access-control-allow-origin"] == studio
        refused = client.post(
            "/clips", files={"file": clip_file(2)}, headers={"Origin": "https://evil.example"}
        )
        assert_error(refused, 403, "cross_site_request")


def test_requests_to_another_name_are_refused(tmp_path: Path) -> None:
    """DNS rebinding: a page at evil.example re-pointed at 127.0.0.1 is same-origin for the
    browser, but its requests carry ``Host: evil.example``."""
    defaults = Settings(data_dir=tmp_path / "data", allowed_hosts=[])
    with client_for(defaults) as client:
        for host in ("evil.example", "evil.example:8000", "localhost.evil.example", "testserver"):
            body = assert_error(
                client.get("/clips", headers={"Host": host}), 400, "host_not_allowed"
            )
            assert "MOCAP_ALLOWED_HOSTS" in body["detail"]
            refused = client.post("/clips", files={"file": clip_file(1)}, headers={"Host": host})
            assert_error(refused, 400, "host_not_allowed")
            # health checks address replicas by any name
            assert client.get("/health", headers={"Host": host}).status_code == 200
        for host in ("localhost", "LOCALHOST:8000", "127.0.0.1:8000", "[::1]:8000", "10.1.2.3"):
            assert client.get("/clips", headers={"Host": host}).status_code == 200, host
        assert client.get("/health").json()["clips"] == 0
    named = Settings(
        data_dir=tmp_path / "data", host="mocap.lan", allowed_hosts=["Mocap.Studio.Example"]
    )
    with client_for(named) as client:
        for host in ("mocap.lan:8000", "mocap.studio.example", "mocap.studio.example.:443"):
            assert client.get("/clips", headers={"Host": host}).status_code == 200, host
        assert_error(
            client.get("/clips", headers={"Host": "evil.example"}), 400, "host_not_allowed"
        )
    anything = Settings(data_dir=tmp_path / "data", allowed_hosts=["*"])
    with client_for(anything) as client:
        assert client.get("/clips", headers={"Host": "evil.example"}).status_code == 200


def test_allowed_hosts_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MOCAP_ALLOWED_HOSTS", "mocap.example, mocap.lan")
    assert Settings().allowed_hosts == ["mocap.example", "mocap.lan"]
    monkeypatch.setenv("MOCAP_ALLOWED_HOSTS", "")
    assert Settings().allowed_hosts == []


def test_the_live_server_refuses_other_names_and_sites(keyed_server: LiveServer) -> None:
    with httpx.Client(base_url=keyed_server.url, timeout=30) as client:
        assert client.get("/clips").status_code == 200  # 127.0.0.1:<port>
        localhost = client.get(f"http://localhost:{keyed_server.port}/clips")
        assert localhost.status_code == 200
        rebound = client.get("/clips", headers={"Host": f"evil.example:{keyed_server.port}"})
        assert_error(rebound, 400, "host_not_allowed")
        cross = client.post(
            "/clips",
            files=unique_upload(5),
            headers={"X-API-Key": KEY, "Origin": "https://evil.example"},
        )
        assert_error(cross, 403, "cross_site_request")
        same = client.post(
            "/clips",
            files=unique_upload(5),
            headers={"X-API-Key": KEY, "Origin": keyed_server.url},
        )
        assert same.status_code == 201, same.text


def test_every_operation_has_the_level_its_rule_gives(settings: Settings) -> None:
    """The guard reads each operation's level from the app's own schema: writes declare the
    write role, uploads and other unsafe operations are heavy, a few reading routes too."""
    from fastapi import APIRouter

    from app.api.guard import Access, operation_access

    app = create_app(settings, describer=FakeDescriber())
    future = APIRouter()
    future.add_api_route("/exports", lambda clip: {}, methods=["POST"])  # no body, no key
    app.include_router(future)
    levels: dict[str, set[tuple[str, str]]] = {}
    for path, item in app.openapi()["paths"].items():
        for method, operation in item.items():
            access = operation_access(method.upper(), path, operation)
            name = access.level.name + ("+heavy" if access.heavy or access.heavy_with else "")
            levels.setdefault(name, set()).add((method.upper(), path))
    assert levels["WRITE+heavy"] == {("POST", "/clips"), ("POST", "/rigs")}  # uploads that store
    assert levels["WRITE"] == {
        ("PATCH", "/clips/{clip_id}"),
        ("DELETE", "/clips/{clip_id}"),
        ("DELETE", "/clips"),
        ("POST", "/clips/labels"),
        ("DELETE", "/rigs/{rig_id}"),
    }
    assert levels["HEAVY+heavy"] == {
        ("POST", "/search"),
        ("POST", "/search/moments"),
        ("POST", "/skeleton"),
        ("POST", "/inspect"),
        ("GET", "/map"),
        ("GET", "/search/moments"),
        ("POST", "/exports"),
    }
    assert levels["READ+heavy"] == {("GET", "/clips/{clip_id}/file")}  # with format/start/end
    assert levels["OPEN"] == {("GET", "/health")}
    assert ("GET", "/search") in levels["READ"] and ("GET", "/clips/{clip_id}/skeleton") in levels[
        "READ"
    ]
    assert Access.OPEN < Access.READ < Access.HEAVY < Access.WRITE
