"""``HEAD`` answered on every ``GET`` route, as RFC 9110 (9.3.2) asks of a server that has GET.

FastAPI registers a route for the methods it names, so ``curl -I /clips/1/file`` was 405.
:class:`HeadAsGet`, the outermost middleware, runs a ``HEAD`` request as the ``GET`` it stands
for (every layer — Host, key, per-client limits, the routes — sees a GET: same checks, same
status and headers, ``Content-Length`` included) and sends no body. The OpenAPI schema is
unchanged: it lists no ``head`` operations, which would only double every GET's entry.

Work a response does after its head is avoided: once the head is sent, the application is
told the client has gone (``http.disconnect``), which ends a streaming or file response, and
whatever body it still sends is dropped. Work done before the head (a search, a conversion)
is done: it is what decides the status and the headers a HEAD must report.
"""

from __future__ import annotations

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

DISCONNECT: Message = {"type": "http.disconnect"}


class HeadAsGet:
    """Pure ASGI middleware: HEAD runs as GET, headers kept, body dropped."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return
        # A copy: the server keeps its own scope saying HEAD (uvicorn drops a HEAD's body too).
        scope = dict(scope, method="GET")
        answered = anyio.Event()

        async def head_only(message: Message) -> None:
            if answered.is_set():
                return  # the rest of a body nobody will read
            if message["type"] == "http.response.start":
                await send(message)
            elif message["type"] == "http.response.body":
                await send({"type": "http.response.body", "body": b"", "more_body": False})
                answered.set()
            else:
                await send(message)

        async def until_answered() -> Message:
            if answered.is_set():
                return DISCONNECT
            message = DISCONNECT
            async with anyio.create_task_group() as group:

                async def client() -> None:
                    nonlocal message
                    message = await receive()
                    group.cancel_scope.cancel()

                async def done() -> None:
                    await answered.wait()
                    group.cancel_scope.cancel()

                group.start_soon(client)
                group.start_soon(done)
            return message

        await self.app(scope, until_answered, head_only)
