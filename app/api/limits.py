"""Request body size limit (413), enforced before the body is read.

Starlette spools uploaded files to disk with no size cap, so the limit is ours: a declared
``Content-Length`` over the limit is refused before a byte of the body is read, and a body
without one (chunked) is counted as it arrives and refused as soon as it passes the limit.

Compressed request bodies (``Content-Encoding`` other than ``identity``) are refused with 415:
the service never decompresses uploads, so no zip or gzip bomb can expand in it.
"""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.errors import error_json
from app.errors import PayloadTooLarge, UnsupportedMediaType


class BodySizeLimit:
    """Pure ASGI middleware; ``max_bytes`` counts the whole body (all multipart parts)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    def _message(self) -> str:
        return f"request body over the {self.max_bytes}-byte limit (MOCAP_MAX_UPLOAD_BYTES)"

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        encoding = _header(scope, b"content-encoding")
        if encoding is not None and encoding.strip().lower() not in (b"", b"identity"):
            shown = encoding.decode("latin-1")[:40]
            response = error_json(
                415,
                UnsupportedMediaType.code,
                f"compressed request bodies are not accepted (Content-Encoding: {shown}); "
                "send the files uncompressed",
            )
            await response(scope, receive, send)
            return
        declared = _content_length(scope)
        if declared is not None and declared > self.max_bytes:
            response = error_json(413, PayloadTooLarge.code, self._message())
            await response(scope, receive, send)
            return

        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    # An HTTPException passes through FastAPI's body parsing unchanged and
                    # reaches the error handlers, which answer 413 in the JSON error shape.
                    raise HTTPException(413, detail=self._message())
            return message

        await self.app(scope, limited_receive, send)


def _header(scope: Scope, wanted: bytes) -> bytes | None:
    for name, value in scope.get("headers", ()):
        if name == wanted:
            return bytes(value)
    return None


def _content_length(scope: Scope) -> int | None:
    value = _header(scope, b"content-length")
    if value is None:
        return None
    try:
        return int(value)
    except ValueError:
        return None
