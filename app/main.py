"""The web application: ``create_app(settings)`` builds it; nothing is created at import.

Run it with ``mocap-index serve`` or ``uvicorn --factory app.main:create_app``.
"""

from __future__ import annotations

import os
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.telemetry import TelemetryConfig
from fastapi_offline import FastAPIOffline
from opentelemetry import _logs, metrics, trace
from starlette.concurrency import run_in_threadpool

from app.api import clips, exports, meta, moments, rigs, search, ui
from app.api.auth import API_KEY_HEADER, log_access_policy, read_dependencies
from app.api.compression import add_compression
from app.api.errors import error_responses, install_error_handlers
from app.api.guard import AccessTable, RequestGuard, document_access, shared_access_table
from app.api.head import HeadAsGet
from app.api.limits import BodySizeLimit, DescribeGate, Slots
from app.api.routers import add_router
from app.config import Settings
from app.services.clips import remove_orphan_files
from app.services.describe import Describer
from app.services.library import open_library

DESCRIPTION = """
Find similar motion-capture clips.

Upload clips (one **BVH**, **FBX**, **glTF** (`.glb`/`.gltf`) or **VRM** (`.vrma`/`.vrm`)
file, or an **ASF** skeleton with an **AMC** motion); each is described under every
descriptor (see `GET /descriptors`) and stored. `GET /search` returns the *k* clips nearest
to a stored clip, `POST /search` those nearest to an uploaded file; `GET` / `POST
/search/moments` find *where* in the stored clips a span of motion happens.

Every error answers `{"error": "<code>", "detail": "<message>"}`.
"""


# The search routes first: a request is matched against the routes in this order.
READING_ROUTERS = (
    search.router,
    moments.router,
    clips.router,
    rigs.router,
    exports.router,
    meta.read_router,
)
# Every router an app of create_app has; its routes never depend on the settings.
ROUTERS = (*READING_ROUTERS, meta.router, ui.router)


def access_table(app: FastAPI) -> AccessTable:
    """The guard's table for ``app``: shared by the apps create_app builds (their routes are
    the same; building one's schema takes 0.3-1 s), unless routes were added to one after."""
    routes_key = (tuple(id(router) for router in ROUTERS), len(app.router.routes))
    return shared_access_table(routes_key, app.openapi)


# The OpenTelemetry API's stand-ins for a provider nobody has set (its own classes).
PLACEHOLDER_PROVIDERS = frozenset(
    {"ProxyTracerProvider", "_ProxyMeterProvider", "ProxyLoggerProvider"}
)


def telemetry_signals(tracer: Any, meter: Any, logger: Any) -> TelemetryConfig:
    """FastAPI's own OpenTelemetry signals (``FastAPI(telemetry=...)``) for these global
    providers: each on when its provider is configured, off when it is the API's stand-in.

    FastAPI asks the three global providers at every request whether one is configured, and
    while none is, each question reads an environment variable (~10 us a request, for no
    span). The answer is taken once, when the app is created — after OpenTelemetry's own
    start-up (``opentelemetry-instrument``) has set any provider. With FastAPI's automatic
    set-up (``FASTAPI_OTEL_AUTO_CONFIGURE=true``: its exporters are made at start), its
    defaults are kept. A provider class this does not know counts as configured (the cost
    stays, never a span lost)."""
    if os.getenv("FASTAPI_OTEL_AUTO_CONFIGURE", "").lower() == "true":
        return {}

    def configured(provider: Any) -> bool:
        return type(provider).__name__ not in PLACEHOLDER_PROVIDERS

    return {"tracing": configured(tracer), "metrics": configured(meter), "logs": configured(logger)}


def _version() -> str:
    try:
        return version("mocap-index")
    except PackageNotFoundError:
        return "0+unknown"


def app_from_environment() -> FastAPI:
    """The application for the ``MOCAP_*`` variables (``mocap-index serve --workers N``: the
    factory each worker process calls)."""
    return create_app(Settings())


def create_app(settings: Settings | None = None, *, describer: Describer | None = None) -> FastAPI:
    """The application for ``settings`` (default: from ``MOCAP_*`` variables).

    The lifespan migrates the database, loads or rebuilds the indexes (and where each window
    lies, for moments search) and keeps the opened library in ``app.state.library``.
    ``describer`` replaces the motion core (tests).
    """
    settings = settings if settings is not None else Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        log_access_policy(settings)
        library = await run_in_threadpool(
            open_library, settings, describer=describer, verify_later=True
        )
        await run_in_threadpool(remove_orphan_files, library)  # left by a crash mid-write
        await run_in_threadpool(library.load_window_places)  # the moments search's map
        library.start_housekeeping()  # prunes the change feed now and then
        # Follow other processes' changes from the start, not from this process's first search.
        await run_in_threadpool(library.refresh)
        app.state.library = library
        try:
            yield
        finally:
            library.close()

    # The docs pages load Swagger UI and ReDoc from files shipped in a package, not a CDN:
    # studio machines are often offline.
    app = FastAPIOffline(
        title="mocap-index",
        version=_version(),
        description=DESCRIPTION,
        lifespan=lifespan,
        telemetry=telemetry_signals(
            trace.get_tracer_provider(), metrics.get_meter_provider(), _logs.get_logger_provider()
        ),
    )
    app.state.settings = settings
    install_error_handlers(app)
    app.state.describe_slots = Slots.for_describes(settings)
    # Innermost: a plain GET /search is answered before FastAPI's routing (app/api/search.py);
    # every layer added below still runs for it.
    app.add_middleware(search.PlainSearches, enabled=not read_dependencies(settings))
    # Inside the size limit: a body over it is refused before the gate counts it.
    app.add_middleware(
        DescribeGate, slots=app.state.describe_slots, max_bytes=settings.max_upload_bytes
    )
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_upload_bytes)
    add_compression(app)  # gzip for larger JSON answers

    # Outside the size limit (and inside CORS, so refusals carry its headers): Host, Origin,
    # API key and per-client limits are checked on the request's head, before its body.
    app.add_middleware(RequestGuard, settings=settings, access_table=lambda: access_table(app))
    if settings.cors_origins:  # CORS is off unless origins are configured
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST", "PATCH", "DELETE"],
            allow_headers=["Authorization", API_KEY_HEADER, "Content-Type"],
            expose_headers=["Location"],
        )
    # Outermost: HEAD is answered as the GET it stands for, without the body (app/api/head.py).
    app.add_middleware(HeadAsGet)
    # Reading routes need a key only with MOCAP_REQUIRE_KEY_FOR_READS; /health never does.
    reads = read_dependencies(settings)
    read_errors = error_responses(401, 403) if reads else {}
    for router in READING_ROUTERS:
        add_router(app, router, dependencies=reads, responses=read_errors)
    add_router(app, meta.router)
    ui.mount_ui(app)  # the web UI at /, /static/*, and the routes it reads (skeletons, map)
    document_access(app, settings)
    return app
