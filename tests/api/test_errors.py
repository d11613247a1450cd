"""One JSON error shape everywhere, and every route documents its errors."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from app.config import Settings
from app.main import create_app
from tests.services.fakes import FakeDescriber, fake_motion

GOOD = ("a.bvh", fake_motion([0, 0, 0]))


def assert_error(response: Any, status: int, code: str, *words: str) -> dict[str, str]:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/json")
    body = response.json()
    assert set(body) == {"error", "detail"}
    assert body["error"] == code
    assert isinstance(body["detail"], str) and body["detail"]
    for word in words:
        assert word in body["detail"]
    return body


@pytest.mark.parametrize(
    ("method", "url", "kwargs", "status", "code", "words"),
    [
        ("get", "/no/such/route", {}, 404, "not_found", ()),
        ("put", "/clips", {}, 405, "method_not_allowed", ()),
        ("get", "/clips/999", {}, 404, "not_found", ("999",)),
        ("get", "/clips/abc", {}, 422, "invalid_input", ("clip_id",)),
        ("get", "/clips/999/file", {}, 404, "not_found", ()),
        ("delete", "/clips/999", {}, 404, "not_found", ()),
        ("patch", "/clips/999", {"json": {"name": "x"}}, 404, "not_found", ()),
        ("get", "/clips?limit=0", {}, 422, "invalid_input", ("limit",)),
        ("get", "/clips?limit=501", {}, 422, "invalid_input", ("limit",)),
        ("get", "/search?clip=999", {}, 404, "not_found", ()),
        ("get", "/search", {}, 422, "invalid_input", ("clip",)),
        ("get", "/search?clip=1&k=abc", {}, 422, "invalid_input", ("k",)),
        ("get", "/search?clip=1&descriptor=nope", {}, 422, "invalid_input", ("posture", "kinetic")),
        (
            "post",
            "/clips",
            {"files": {"file": ("a.obj", b"x")}},
            415,
            "unsupported_media_type",
            ("'file'",),
        ),
        ("post", "/clips", {"json": {"file": "x"}}, 415, "unsupported_media_type", ("multipart",)),
        (
            "post",
            "/clips",
            {"data": {"name": "x"}, "files": {"other": GOOD}},
            422,
            "invalid_input",
            ("'file'",),
        ),
        (
            "post",
            "/clips",
            {"files": {"skeleton": ("a.asf", b"s")}},
            422,
            "invalid_input",
            ("'motion'",),
        ),
        (
            "post",
            "/clips",
            {"files": {"motion": ("a.amc", b"m")}},
            422,
            "invalid_input",
            ("'skeleton'",),
        ),
        (
            "post",
            "/clips",
            {"files": {"file": GOOD, "skeleton": ("a.asf", b"s")}},
            422,
            "invalid_input",
            ("not both",),
        ),
        (
            "post",
            "/clips",
            {"files": {"file": ("a.bvh", b"{oops")}},
            422,
            "parse_error",
            ("line 1", "a.bvh"),
        ),
        ("post", "/clips", {"files": {"file": ("a.bvh", b"")}}, 422, "invalid_input", ("empty",)),
        (
            "post",
            "/search",
            {"files": {"file": ("a.txt", b"x")}},
            415,
            "unsupported_media_type",
            (),
        ),
        ("post", "/search?k=0", {"files": {"file": GOOD}}, 422, "invalid_input", ("k",)),
        # A text value where a file belongs: the API's words, not pydantic's class names.
        (
            "post",
            "/clips",
            {"files": {"file": (None, b"HIERARCHY")}},
            422,
            "invalid_input",
            ("file", "must be a file"),
        ),
        # A second skeleton or motion was dropped without a word (the last one was stored).
        (
            "post",
            "/clips",
            {
                "files": [
                    ("skeleton", ("a.asf", b"s")),
                    ("motion", ("a.amc", b"m")),
                    ("motion", ("b.amc", b"n")),
                ]
            },
            422,
            "invalid_input",
            ("field 'motion'", "not 2", "'a.amc'", "'b.amc'"),
        ),
        (
            "post",
            "/search",
            {"files": [("skeleton", ("a.asf", b"s")), ("skeleton", ("b.asf", b"t"))]},
            422,
            "invalid_input",
            ("field 'skeleton'", "not 2"),
        ),
        # Malformed JSON is 400, naming where it breaks (it was 422 "10: JSON decode error").
        (
            "post",
            "/clips/labels",
            {"content": b'{"ids": [1,', "headers": {"content-type": "application/json"}},
            400,
            "bad_request",
            ("body: not valid JSON at character 11",),
        ),
        (
            "patch",
            "/clips/1",
            {"content": b"{'name': 'x'}", "headers": {"content-type": "application/json"}},
            400,
            "bad_request",
            ("body: not valid JSON",),
        ),
    ],
)
def test_error_shape(
    fake_client: TestClient,
    method: str,
    url: str,
    kwargs: dict[str, Any],
    status: int,
    code: str,
    words: tuple[str, ...],
) -> None:
    response = getattr(fake_client, method)(url, **kwargs)
    assert_error(response, status, code, *words)


def test_errors_about_an_existing_clip(fake_client: TestClient) -> None:
    clip = fake_client.post("/clips", files={"file": GOOD}).json()
    url = f"/search?clip={clip['id']}"
    for k in (0, 1001):
        assert_error(fake_client.get(f"{url}&k={k}"), 422, "invalid_input", "between 1 and 1000")
    assert fake_client.get(f"{url}&k=1000").status_code == 200
    assert_error(fake_client.get(f"/clips/{clip['id']}?include=nope"), 422, "invalid_input")
    assert_error(fake_client.get(f"/clips/{clip['id']}/file?part=motion"), 422, "invalid_input")
    patch = fake_client.patch(f"/clips/{clip['id']}", json={"colour": "red"})
    assert_error(patch, 422, "invalid_input", "colour")
    assert_error(
        fake_client.patch(f"/clips/{clip['id']}", json={"name": "  "}), 422, "invalid_input"
    )


@pytest.fixture
def small_client(settings: Settings) -> Iterator[TestClient]:
    small = settings.model_copy(update={"max_upload_bytes": 2000})
    with TestClient(create_app(small, describer=FakeDescriber())) as client:
        yield client


def test_upload_over_the_size_limit_is_refused_before_it_is_read(small_client: TestClient) -> None:
    big = ("big.bvh", b" " * 5000)
    for url in ("/clips", "/search"):
        response = small_client.post(url, files={"file": big})
        assert_error(response, 413, "payload_too_large", "2000")
    assert small_client.get("/clips").json()["total"] == 0


def test_chunked_upload_over_the_limit_is_cut_off(small_client: TestClient) -> None:
    def body() -> Iterator[bytes]:
        yield b'--xx\r\nContent-Disposition: form-data; name="file"; filename="a.bvh"\r\n\r\n'
        for _ in range(100):  # 100 kB in all, far over the limit
            yield b"x" * 1000
        yield b"\r\n--xx--\r\n"

    response = small_client.post(
        "/clips", content=body(), headers={"content-type": "multipart/form-data; boundary=xx"}
    )
    assert "content-length" not in {k.lower() for k in response.request.headers}
    assert_error(response, 413, "payload_too_large")
    assert small_client.get("/clips").json()["total"] == 0


def test_every_route_documents_its_errors(fake_client: TestClient) -> None:
    schema = fake_client.get("/openapi.json").json()
    assert fake_client.get("/docs").status_code == 200
    error_ref = "#/components/schemas/ErrorResponse"
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            responses = operation["responses"]
            errors = {s: r for s, r in responses.items() if s[0] in "45"}
            takes_input = bool(operation.get("parameters") or operation.get("requestBody"))
            if takes_input:
                assert "422" in errors, (method, path)
            for status, response in errors.items():
                content = response["content"]["application/json"]
                assert content["schema"]["$ref"] == error_ref, (method, path, status)
                assert content["examples"], (method, path, status)
            assert operation.get("summary") and operation.get("description"), (method, path)
    upload = schema["paths"]["/clips"]["post"]
    assert {"413", "415", "422"} <= set(upload["responses"])
    form = upload["requestBody"]["content"]["multipart/form-data"]["schema"]["$ref"].split("/")[-1]
    assert {"file", "skeleton", "motion", "name", "labels"} <= set(
        schema["components"]["schemas"][form]["properties"]
    )


def test_database_and_unexpected_errors_keep_the_shape(
    settings: Settings, monkeypatch: pytest.MonkeyPatch
) -> None:
    from sqlalchemy.exc import OperationalError

    from app.db import clips as clip_db

    def locked(*args: object) -> int:
        raise OperationalError("SELECT", {}, Exception("database is locked"))

    def bug(*args: object) -> object:
        raise RuntimeError("a bug")

    app = create_app(settings, describer=FakeDescriber())
    with TestClient(app, raise_server_exceptions=False) as client:
        monkeypatch.setattr(clip_db, "count_clips", locked)
        assert_error(client.get("/health"), 503, "storage_unavailable")
        monkeypatch.setattr(clip_db, "list_clips", bug)
        assert_error(client.get("/clips"), 500, "internal_error")
