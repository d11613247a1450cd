"""A malformed multipart body is refused saying what is wrong with it, naming the field, and
nothing is stored (app/api/forms.py, and the repeated-field check of app/api/deps.py)."""

from __future__ import annotations

import pytest
from fastapi.testclient import TestClient

from tests.api.conftest import stored_blobs
from tests.api.test_errors import assert_error
from tests.services.fakes import fake_motion

BOUNDARY = "b0undary"
HEADERS = {"content-type": f"multipart/form-data; boundary={BOUNDARY}"}
BVH = fake_motion([1, 0, 0])
UPLOAD_ROUTES = ["/clips", "/search", "/search/moments", "/skeleton", "/inspect", "/rigs"]


def part(name: bytes, value: bytes, filename: bytes | None = None) -> bytes:
    disposition = b'form-data; name="' + name + b'"'
    if filename is not None:
        disposition += b'; filename="' + filename + b'"'
    return (
        b"--"
        + BOUNDARY.encode()
        + b"\r\nContent-Disposition: "
        + disposition
        + b"\r\n\r\n"
        + value
        + b"\r\n"
    )


def body(*parts: bytes, closed: bool = True) -> bytes:
    return b"".join(parts) + (b"--" + BOUNDARY.encode() + b"--\r\n" if closed else b"")


def assert_nothing_stored(client: TestClient, settings: object) -> None:
    assert client.get("/clips").json()["total"] == 0
    assert client.get("/rigs").json()["total"] == 0
    assert stored_blobs(settings) == []  # type: ignore[arg-type]


@pytest.mark.parametrize("field", ["name", "source", "licence", "animation", "labels"])
def test_a_text_field_of_invalid_utf8_is_refused_naming_it(
    fake_client: TestClient, settings: object, field: str
) -> None:
    raw = body(part(b"file", BVH, b"a.bvh"), part(field.encode(), b"walk \xff\xfe"))
    response = fake_client.post("/clips", content=raw, headers=HEADERS)
    assert_error(response, 422, "invalid_input", f"field '{field}'", "not valid utf-8")
    assert_nothing_stored(fake_client, settings)


@pytest.mark.parametrize("url", UPLOAD_ROUTES)
def test_a_file_name_of_invalid_utf8_is_refused_naming_the_field(
    fake_client: TestClient, settings: object, url: str
) -> None:
    raw = body(part(b"file", BVH, b"walk\xff\xfe.bvh"))
    response = fake_client.post(url, content=raw, headers=HEADERS)
    assert_error(response, 422, "invalid_input", "field 'file'", "file name", "not valid utf-8")
    assert_nothing_stored(fake_client, settings)


def test_utf8_text_and_file_names_are_kept_as_sent(fake_client: TestClient) -> None:
    raw = body(
        part(b"file", BVH, "pas de deux é.bvh".encode()), part(b"name", "Ünïcode ✓".encode())
    )
    response = fake_client.post("/clips", content=raw, headers=HEADERS)
    assert response.status_code == 201, response.text
    assert response.json()["name"] == "Ünïcode ✓"
    assert response.json()["filenames"] == ["pas de deux é.bvh"]


@pytest.mark.parametrize("field", ["name", "source", "licence", "animation"])
def test_a_repeated_single_valued_field_is_refused_naming_it(
    fake_client: TestClient, settings: object, field: str
) -> None:
    files = [("file", ("a.bvh", BVH)), (field, (None, "first")), (field, (None, "second"))]
    response = fake_client.post("/clips", files=files)
    assert_error(response, 422, "invalid_input", f"field '{field}'", "not 2", "'first'")
    assert_nothing_stored(fake_client, settings)


def test_a_repeated_rig_name_is_refused(fake_client: TestClient, settings: object) -> None:
    files = [("file", ("a.bvh", BVH)), ("name", (None, "one")), ("name", (None, "two"))]
    response = fake_client.post("/rigs", files=files)
    assert_error(response, 422, "invalid_input", "field 'name'", "not 2")
    assert_nothing_stored(fake_client, settings)


def test_repeated_labels_are_still_several_labels(fake_client: TestClient) -> None:
    files = [("file", ("a.bvh", BVH)), ("labels", (None, "walk")), ("labels", (None, "happy"))]
    response = fake_client.post("/clips", files=files)
    assert response.status_code == 201, response.text
    assert sorted(response.json()["labels"]) == ["happy", "walk"]


@pytest.mark.parametrize("url", UPLOAD_ROUTES)
def test_a_body_without_its_closing_boundary_is_400_truncated(
    fake_client: TestClient, settings: object, url: str
) -> None:
    raw = body(part(b"file", BVH, b"a.bvh"), closed=False)
    response = fake_client.post(url, content=raw, headers=HEADERS)
    assert_error(response, 400, "bad_request", "multipart body", "truncated", "closing boundary")
    assert_nothing_stored(fake_client, settings)


def test_a_body_cut_in_the_middle_of_a_part_is_400_truncated(fake_client: TestClient) -> None:
    raw = body(part(b"file", BVH, b"a.bvh"))
    raw = raw[: raw.index(BVH) + len(BVH) // 2]
    response = fake_client.post("/clips", content=raw, headers=HEADERS)
    assert_error(response, 400, "bad_request", "truncated", "part 1")


def test_an_empty_multipart_body_is_still_no_upload(fake_client: TestClient) -> None:
    response = fake_client.post("/clips", content=b"", headers=HEADERS)
    assert_error(response, 422, "invalid_input", "no upload")


def test_a_100_kb_file_name_is_400_naming_the_part_and_field(
    fake_client: TestClient, settings: object
) -> None:
    files = {"file": ("a" * 100_000 + ".bvh", BVH)}
    response = fake_client.post("/clips", files=files)
    assert_error(response, 400, "bad_request", "header of part 1", "field 'file'")
    assert "longer than" in response.json()["detail"]
    assert_nothing_stored(fake_client, settings)


def test_other_malformed_bodies_say_why(fake_client: TestClient) -> None:
    raw = b"--" + BOUNDARY.encode() + b"XX\r\n"
    response = fake_client.post("/clips", content=raw, headers=HEADERS)
    assert_error(response, 400, "bad_request", "multipart body: ")
    no_boundary = {"content-type": "multipart/form-data"}
    response = fake_client.post(
        "/clips", content=body(part(b"file", BVH, b"a.bvh")), headers=no_boundary
    )
    assert_error(response, 400, "bad_request", "multipart body: ", "boundary")
