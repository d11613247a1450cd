"""Compressed answers: gzip for JSON and the web UI's text files, for clients that accept it.

A search of 50 clips fetches 51 skeletons; gzip makes their JSON a quarter of its size and
the API's other JSON smaller too. Left alone: answers under :data:`MINIMUM_BYTES` (the
headers would cost more than the bytes saved), downloads (``application/octet-stream``, ZIP:
sent byte for byte, as stored) and what is compressed already (Starlette's list). Request
bodies are not touched: the service refuses compressed uploads (``app.api.limits``).

:class:`Compression` answers exactly as Starlette's ``GZipMiddleware`` does — it hands
clients that accept gzip to it — but answers the others (``wrk``, scripts, most API clients)
without it: Starlette builds a responder per request, normalises its list of excluded types
again and parses the response's headers twice just to add ``Vary: Accept-Encoding`` to the
larger answers, ~30 us a request, a fifth of the framework's time around a search
(bench/README.md). ``tests/api/test_compression.py`` compares the two message by message.
"""

from __future__ import annotations

from fastapi import FastAPI
from starlette.datastructures import MutableHeaders
from starlette.middleware.gzip import DEFAULT_EXCLUDED_CONTENT_TYPES, GZipMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MINIMUM_BYTES = 1024
LEVEL = 6  # zlib's default: level 9 costs twice the time for ~2 % less
EXCLUDED_TYPES = (*DEFAULT_EXCLUDED_CONTENT_TYPES, "application/octet-stream")
VARY = b"vary"
LATER_MESSAGES = frozenset(
    {"http.response.body", "http.response.early_hint", "http.response.trailers"}
)


def add_compression(app: FastAPI) -> None:
    """Compress ``app``'s larger answers (see the module docstring)."""
    app.add_middleware(
        Compression,
        minimum_size=MINIMUM_BYTES,
        compresslevel=LEVEL,
        exclude_content_types=EXCLUDED_TYPES,
    )


def accepts_gzip(scope: Scope) -> bool:
    """Whether the request's first ``Accept-Encoding`` header names gzip (as Starlette's
    ``Headers.get`` reads it)."""
    for name, value in scope["headers"]:
        if name == b"accept-encoding":
            return b"gzip" in value
    return False


class Compression:
    """Pure ASGI middleware: Starlette's ``GZipMiddleware`` for clients that accept gzip;
    for the others, the same answers (``Vary: Accept-Encoding`` on those it would have
    compressed) with no responder object and no header parsing of small answers."""

    def __init__(
        self,
        app: ASGIApp,
        minimum_size: int,
        compresslevel: int,
        exclude_content_types: tuple[str, ...],
    ) -> None:
        self.app = app
        self.minimum_size = minimum_size
        self.gzip = GZipMiddleware(
            app,
            minimum_size=minimum_size,
            compresslevel=compresslevel,
            exclude_content_types=exclude_content_types,
        )
        self.excluded = frozenset(self.gzip.exclude_content_types)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or accepts_gzip(scope):
            await self.gzip(scope, receive, send)
            return
        await self.app(scope, receive, IdentitySend(send, self.minimum_size, self.excluded))


class IdentitySend:
    """The ``send`` of an answer sent uncompressed: Starlette's ``IdentityResponder``'s
    messages, in its order (the head held until the first body says whether to add
    ``Vary``)."""

    __slots__ = ("excluded", "head", "minimum_size", "passing", "send", "started")

    def __init__(self, send: Send, minimum_size: int, excluded: frozenset[str]) -> None:
        self.send = send
        self.minimum_size = minimum_size
        self.excluded = excluded
        self.head: Message = {}
        self.passing = False  # encoded already, partial or of an excluded type: untouched
        self.started = False

    async def __call__(self, message: Message) -> None:
        kind = message["type"]
        if kind == "http.response.start":
            self.head = message
            self.passing = self._untouched(message)
            if self.passing:
                await self.send(message)
        elif self.passing and kind in ("http.response.body", "http.response.pathsend"):
            await self.send(message)
        elif kind == "http.response.body" and not self.started:
            self.started = True
            body = message.get("body", b"")
            if len(body) >= self.minimum_size or message.get("more_body", False):
                add_vary(self.head["headers"])
            await self.send(self.head)
            await self.send(message)
        elif kind == "http.response.pathsend":
            await self.send(self.head)
            await self.send(message)
        elif kind in LATER_MESSAGES:  # later bodies of a stream, early hints, trailers
            await self.send(message)

    def _untouched(self, head: Message) -> bool:
        """Whether the answer of ``head`` is passed as it is (see Starlette's responder)."""
        headers = head.setdefault("headers", [])
        if head["status"] == 206:
            return True
        media_type = ""
        found_type = False
        for name, value in headers:
            if name == b"content-encoding":
                return True
            if name == b"content-type" and not found_type:
                found_type = True
                media_type = value.decode("latin-1").partition(";")[0].strip().lower()
        media_types = {media_type, media_type.partition("/")[0] + "/*"}
        if media_type.startswith("application/grpc+"):
            media_types.add("application/grpc")
        return not media_types.isdisjoint(self.excluded)


def add_vary(headers: list[tuple[bytes, bytes]]) -> None:
    """Add ``Accept-Encoding`` to the ``Vary`` of the raw ``headers`` (in place)."""
    if any(name == VARY for name, _ in headers):
        MutableHeaders(raw=headers).add_vary_header("Accept-Encoding")
    else:
        headers.append((VARY, b"Accept-Encoding"))
