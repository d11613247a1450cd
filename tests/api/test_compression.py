"""The compression layer answers as Starlette's GZipMiddleware does, message by message.

Each case is a small real ASGI app (a response of some type, size, status and headers,
whole or streamed) wrapped once in :class:`app.api.compression.Compression` and once in
Starlette's ``GZipMiddleware`` with the same settings; both are called with the same request
(with and without ``Accept-Encoding: gzip``) and must send the same messages.
"""

from __future__ import annotations

import asyncio
import gzip
from collections.abc import AsyncIterator
from typing import Any

import pytest
from starlette.middleware.gzip import GZipMiddleware
from starlette.responses import Response, StreamingResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.compression import EXCLUDED_TYPES, LEVEL, MINIMUM_BYTES, Compression

BIG = b'{"results":[' + b'{"id":1,"name":"walk"},' * 100 + b"{}]}"
SMALL = b'{"status":"ok"}'


def whole(body: bytes, media_type: str | None, **kwargs: Any) -> ASGIApp:
    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        await Response(body, media_type=media_type, **kwargs)(scope, receive, send)

    return app


def streamed(parts: list[bytes], media_type: str) -> ASGIApp:
    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        async def chunks() -> AsyncIterator[bytes]:
            for part in parts:
                yield part

        await StreamingResponse(chunks(), media_type=media_type)(scope, receive, send)

    return app


def raw_messages(messages: list[Message]) -> ASGIApp:
    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        for message in messages:
            await send(dict(message, headers=list(message.get("headers", []))))

    return app


CASES = {
    "large JSON": whole(BIG, "application/json"),
    "small JSON": whole(SMALL, "application/json"),
    "exactly the minimum": whole(b"x" * MINIMUM_BYTES, "text/plain"),
    "one byte under": whole(b"x" * (MINIMUM_BYTES - 1), "text/plain"),
    "download": whole(BIG, "application/octet-stream"),
    "image": whole(BIG, "image/png"),
    "type with parameters": whole(BIG, "Text/HTML; charset=utf-8"),
    "video family": whole(BIG, "video/mp4"),
    "gRPC variant": whole(BIG, "application/grpc+proto"),
    "no content type": whole(BIG, None),
    "encoded already": whole(BIG, "application/json", headers={"Content-Encoding": "br"}),
    "vary already": whole(BIG, "application/json", headers={"Vary": "Origin"}),
    "partial content": whole(BIG, "application/json", status_code=206),
    "error status": whole(BIG, "application/json", status_code=404),
    "stream": streamed([BIG, SMALL, b""], "application/json"),
    "small stream": streamed([SMALL], "text/plain"),
    "excluded stream": streamed([BIG, BIG], "text/event-stream"),
    "trailers": raw_messages(
        [
            {
                "type": "http.response.start",
                "status": 200,
                "headers": [(b"content-type", b"text/plain")],
                "trailers": True,
            },
            {"type": "http.response.body", "body": BIG, "more_body": False},
            {"type": "http.response.trailers", "headers": [], "more_trailers": False},
        ]
    ),
    "unknown message": raw_messages(
        [
            {"type": "http.response.start", "status": 200, "headers": []},
            {"type": "http.response.mystery"},
            {"type": "http.response.body", "body": SMALL},
        ]
    ),
}


def call(app: ASGIApp, accept: bytes | None) -> list[Message]:
    headers = [(b"host", b"testserver")]
    if accept is not None:
        headers.append((b"accept-encoding", accept))
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "GET",
        "scheme": "http",
        "path": "/",
        "raw_path": b"/",
        "query_string": b"",
        "headers": headers,
        "client": ("127.0.0.1", 1),
        "server": ("testserver", 80),
    }
    sent: list[Message] = []
    requests = [{"type": "http.request", "body": b"", "more_body": False}]

    async def receive() -> Message:
        if requests:
            return requests.pop()
        await asyncio.Event().wait()  # the client stays: a stream ends by itself
        raise AssertionError("unreachable")

    async def send(message: Message) -> None:
        sent.append(message)

    asyncio.run(asyncio.wait_for(app(scope, receive, send), 10))
    return sent


@pytest.mark.parametrize("accept", [None, b"gzip, deflate", b"br", b"identity", b""])
@pytest.mark.parametrize("case", sorted(CASES))
def test_the_same_messages_as_starlettes_gzip(case: str, accept: bytes | None) -> None:
    ours = Compression(
        CASES[case],
        minimum_size=MINIMUM_BYTES,
        compresslevel=LEVEL,
        exclude_content_types=EXCLUDED_TYPES,
    )
    theirs = GZipMiddleware(
        CASES[case],
        minimum_size=MINIMUM_BYTES,
        compresslevel=LEVEL,
        exclude_content_types=EXCLUDED_TYPES,
    )
    assert call(ours, accept) == call(theirs, accept)


def test_large_answers_are_compressed_for_clients_that_ask() -> None:
    """Not a tautology of the comparison above: gzip is really applied, and only then."""
    app = Compression(
        CASES["large JSON"],
        minimum_size=MINIMUM_BYTES,
        compresslevel=LEVEL,
        exclude_content_types=EXCLUDED_TYPES,
    )
    head, body = call(app, b"gzip")
    assert (b"content-encoding", b"gzip") in head["headers"]
    assert gzip.decompress(body["body"]) == BIG
    head, body = call(app, None)
    assert (b"vary", b"Accept-Encoding") in head["headers"]
    assert body["body"] == BIG
    assert all(name != b"content-encoding" for name, _ in head["headers"])
