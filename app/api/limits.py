"""Request limits: body size (413, before the body is read) and concurrent describes (503).

Starlette spools uploaded files to disk with no size cap, so the limit is ours: a declared
``Content-Length`` over the limit is refused before a byte of the body is read, and a body
without one (chunked) is counted as it arrives and refused as soon as it passes the limit.

Compressed request bodies (``Content-Encoding`` other than ``identity``) are refused with 415:
the service never decompresses uploads, so no zip or gzip bomb can expand in it.

Describing an upload (parse, kinematics, descriptors) takes CPU and up to
:func:`describe_bytes` of memory, so a process describes at most :func:`describe_slots`
uploads at once (:class:`Slots`, taken by every route that reads an upload). A request waits
for a slot with its body spooled to disk, on the event loop (no thread, no memory), up to
``MOCAP_DESCRIBE_WAIT_SECONDS``; then 503 ``busy`` with ``Retry-After``. Parsing a multipart
body is work on the event loop, so the uploads let in at once may declare at most ``slots x
MOCAP_MAX_UPLOAD_BYTES`` together (:class:`DescribeGate`; one is always let in): beyond, an
upload is answered 503 ``busy`` at once, its body drained unread (a client sending its body
before reading the answer still gets it). Many small uploads wait; few large ones do.
"""

from __future__ import annotations

import asyncio
import math
import os
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.errors import error_json
from app.config import Settings
from app.errors import PayloadTooLarge, ServiceBusy, UnsupportedMediaType

# Peak memory of describing one clip per number its frames expand to (MOCAP_MAX_FRAME_VALUES
# counts them): 644 MB for a real BVH at the 20-million cap (bench/bench_busy.py), with room.
BYTES_PER_FRAME_VALUE = 36
# The upload's bytes are held twice meanwhile (the request's copy, the parser's text).
UPLOAD_COPIES = 2


def describe_bytes(settings: Settings) -> int:
    """Most memory describing one upload may take, from the limits that bound it."""
    return (
        settings.max_frame_values * BYTES_PER_FRAME_VALUE
        + settings.max_upload_bytes * UPLOAD_COPIES
    )


def _physical_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError):
        return 4 * 2**30


def describe_slots(settings: Settings) -> int:
    """Uploads one process describes at once: ``MOCAP_MAX_CONCURRENT_DESCRIBES``, or one per
    CPU core but one — kept for the event loop, ``/health`` and searches (on 2 cores, two
    describes at the cap took twice as long each, past the describe time limit, and held
    ``/health`` up to 4 s; one kept it under 1 s: bench/README.md) — as long as half the
    machine's memory holds them all at :func:`describe_bytes` each; at least one."""
    if settings.max_concurrent_describes:
        return settings.max_concurrent_describes
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    fitting = _physical_memory() // 2 // describe_bytes(settings)
    return max(1, min((cores or 1) - 1, fitting))


class Slots:
    """At most ``size`` holders at once, first come first served; a caller waits up to
    ``wait_seconds`` for a slot, then gets :class:`ServiceBusy` (503 with ``Retry-After``).

    Waits on the event loop (an :class:`asyncio.Semaphore` of the loop it is used on)."""

    def __init__(self, size: int, *, wait_seconds: float, doing: str, setting: str) -> None:
        self.size = size
        self.wait_seconds = wait_seconds
        self.doing = doing
        self.setting = setting
        self._loop: asyncio.AbstractEventLoop | None = None
        self._semaphore = asyncio.Semaphore(size)
        self.waiting = 0
        self.admitted = 0  # requests past the gate: reading their body, waiting or holding
        self.admitted_bytes = 0  # the bodies they declared

    def busy(self, retry_after: float | None = None) -> ServiceBusy:
        return ServiceBusy(
            f"the server is busy {self.doing} ({self.size} at once, {self.setting}; "
            f"{self.waiting} waiting); try again in a few seconds",
            retry_after=math.ceil(max(1.0, retry_after or self.wait_seconds)),
        )

    @classmethod
    def for_describes(cls, settings: Settings) -> Slots:
        return cls(
            describe_slots(settings),
            wait_seconds=settings.describe_wait_seconds,
            doing="describing uploads",
            setting="MOCAP_MAX_CONCURRENT_DESCRIBES",
        )

    def _semaphore_here(self) -> asyncio.Semaphore:
        loop = asyncio.get_running_loop()
        if self._loop is not loop:  # a new event loop (a test client entered again)
            self._loop, self._semaphore = loop, asyncio.Semaphore(self.size)
        return self._semaphore

    @asynccontextmanager
    async def hold(self) -> AsyncIterator[None]:
        semaphore = self._semaphore_here()
        self.waiting += 1
        try:
            await asyncio.wait_for(semaphore.acquire(), timeout=self.wait_seconds)
        except TimeoutError:
            raise self.busy() from None
        finally:
            self.waiting -= 1
        try:
            yield
        finally:
            semaphore.release()


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


# The routes that read an upload (UploadDep); tests/api/test_limits_gate.py checks the list.
UPLOAD_ROUTES = frozenset(
    {"/clips", "/search", "/search/moments", "/skeleton", "/inspect", "/rigs"}
)


# How fast an upload let in by the gate must send its body (it holds part of the gate's
# budget meanwhile): anything in its first 10 s, then at least 64 KiB/s on average (a
# 512 kbit/s line; 256 MiB, the default size limit, in 68 minutes). Slower gets 408. Fixed:
# a client that cannot keep this up holds back every other client's uploads.
BODY_GRACE_SECONDS = 10.0
BODY_MIN_BYTES_PER_SECOND = 64 * 1024


class DescribeGate:
    """Pure ASGI middleware: an upload (POST to :data:`UPLOAD_ROUTES`) whose body would take
    the bodies let in past ``slots.size x max_bytes`` gets 503 ``busy`` before its body is
    parsed (drained unread, so the client reads the answer); a body without a length counts
    as ``max_bytes``. One upload is always let in."""

    def __init__(
        self,
        app: ASGIApp,
        slots: Slots,
        max_bytes: int,
        *,
        grace_seconds: float = BODY_GRACE_SECONDS,
        min_bytes_per_second: int = BODY_MIN_BYTES_PER_SECOND,
    ) -> None:
        self.app = app
        self.slots = slots
        self.budget = slots.size * max_bytes
        self.max_bytes = max_bytes
        self.grace_seconds = grace_seconds
        self.min_bytes_per_second = min_bytes_per_second

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        gated = (
            scope["type"] == "http"
            and scope.get("method") == "POST"
            and scope.get("path", "").rstrip("/") in UPLOAD_ROUTES
        )
        if not gated:
            await self.app(scope, receive, send)
            return
        slots = self.slots
        declared = _content_length(scope)
        size = self.max_bytes if declared is None else min(declared, self.max_bytes)
        if slots.admitted and slots.admitted_bytes + size > self.budget:
            while True:  # unread: no multipart parsing, nothing kept
                message = await receive()
                if message["type"] != "http.request" or not message.get("more_body", False):
                    break
            error = slots.busy()
            response = error_json(
                503, error.code, error.detail, {"Retry-After": str(error.retry_after)}
            )
            await response(scope, receive, send)
            return
        slots.admitted += 1
        slots.admitted_bytes += size
        try:
            await self.app(scope, self._paced(receive, declared), send)
        finally:
            slots.admitted -= 1
            slots.admitted_bytes -= size

    def _paced(self, receive: Receive, declared: int | None) -> Receive:
        """``receive`` of an admitted upload, which must keep its body coming: by
        ``grace_seconds`` + (bytes received) / ``min_bytes_per_second`` after it was let in
        the next bytes must have arrived, else 408 and the budget it reserved is free again.
        Without this one client that sends a head declaring a large body and then stalls
        (or sends a byte now and then) held the whole budget for as long as it liked, and
        every other upload of every client was answered 503 ``busy``."""
        started = time.monotonic()
        received = 0
        complete = False

        async def paced_receive() -> Message:
            nonlocal received, complete
            if complete:  # the body is in: a later receive waits for a disconnect, unbounded
                return await receive()
            deadline = started + self.grace_seconds + received / self.min_bytes_per_second
            try:
                message = await asyncio.wait_for(
                    receive(), timeout=max(0.0, deadline - time.monotonic())
                )
            except TimeoutError:
                elapsed = time.monotonic() - started
                of = "" if declared is None else f" of {declared}"
                raise HTTPException(
                    408,
                    detail=(
                        f"the upload's body came too slowly: {received}{of} bytes in "
                        f"{elapsed:.0f} s; after its first {self.grace_seconds:g} s an upload "
                        f"must arrive at {self.min_bytes_per_second // 1024} KiB/s or more"
                    ),
                ) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                complete = not message.get("more_body", False)
            else:
                complete = True
            return message

        return paced_receive
