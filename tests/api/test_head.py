"""HEAD is answered on every GET route as GET is, without the body (app/api/head.py)."""

from __future__ import annotations

import anyio
import pytest
from fastapi.routing import APIRoute
from fastapi.testclient import TestClient

from app.main import create_app
from tests.services.fakes import FakeDescriber, fake_motion

# Headers that must be the same for HEAD and GET (Date and the like may differ).
COMPARED = ("content-type", "content-length", "content-disposition", "etag", "cache-control")


def assert_head_like_get(client: TestClient, url: str) -> int:
    get = client.get(url)
    head = client.head(url)
    assert head.status_code == get.status_code, (url, head.status_code, get.text)
    assert head.content == b"", url
    for name in COMPARED:
        assert head.headers.get(name) == get.headers.get(name), (url, name)
    return get.status_code


def test_head_on_every_get_route_answers_as_get_without_the_body(
    fake_client: TestClient,
) -> None:
    clip = fake_client.post("/clips", files={"file": ("walk.bvh", fake_motion([1, 0, 0]))})
    assert clip.status_code == 201, clip.text
    clip_id = clip.json()["id"]
    app = fake_client.app
    urls = ["/", "/static/app.js", "/clips/1/file?format=bvh", f"/search?clip={clip_id}"]
    for route in app.routes:  # type: ignore[attr-defined]
        if isinstance(route, APIRoute) and "GET" in route.methods:
            urls.append(route.path.replace("{clip_id}", str(clip_id)).replace("{rig_id}", "1"))
    statuses = {url: assert_head_like_get(fake_client, url) for url in urls}
    # The finding: the download answered 405 to HEAD.
    assert statuses[f"/clips/{clip_id}/file"] == 200
    assert statuses["/clips"] == 200
    assert statuses["/rigs/1"] == 404  # errors too: the same status, no body
    assert fake_client.head(f"/clips/{clip_id}/file").headers["content-length"] == str(
        len(fake_motion([1, 0, 0]))
    )


def test_head_is_not_allowed_where_get_is_not(fake_client: TestClient) -> None:
    response = fake_client.head("/exports")  # POST only
    assert response.status_code == 405
    assert response.content == b""
    assert fake_client.head("/no/such/route").status_code == 404


def test_head_takes_the_read_key_as_get_does(settings: object) -> None:
    keyed = settings.model_copy(  # type: ignore[attr-defined]
        update={"api_key": "s3cret", "require_key_for_reads": True}
    )
    with TestClient(create_app(keyed, describer=FakeDescriber())) as client:
        assert client.head("/clips").status_code == 401
        assert client.head("/clips", headers={"X-API-Key": "s3cret"}).status_code == 200


def test_the_schema_lists_no_head_operations(fake_client: TestClient) -> None:
    paths = fake_client.get("/openapi.json").json()["paths"]
    assert not [path for path, operations in paths.items() if "head" in operations]


@pytest.mark.anyio
async def test_a_streamed_body_stops_once_the_head_is_sent() -> None:
    from starlette.responses import StreamingResponse

    from app.api.head import HeadAsGet

    produced: list[int] = []

    async def chunks():  # type: ignore[no-untyped-def]
        for n in range(1000):
            produced.append(n)
            yield b"x" * 1000
            await anyio.sleep(0.001)

    async def app(scope, receive, send):  # type: ignore[no-untyped-def]
        await StreamingResponse(chunks())(scope, receive, send)

    sent: list[dict[str, object]] = []

    async def receive():  # type: ignore[no-untyped-def]
        await anyio.sleep(3600)

    async def send(message):  # type: ignore[no-untyped-def]
        sent.append(message)

    scope = {"type": "http", "method": "HEAD", "path": "/", "headers": [], "asgi": {}}
    await HeadAsGet(app)(scope, receive, send)
    assert [m["type"] for m in sent] == ["http.response.start", "http.response.body"]
    assert sent[1] == {"type": "http.response.body", "body": b"", "more_body": False}
    assert len(produced) < 10  # the stream was ended, not run to its 1000 chunks
