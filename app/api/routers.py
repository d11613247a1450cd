"""Adding a module's router to an app without FastAPI building its routes again for each app."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fastapi import APIRouter, FastAPI
from fastapi.params import Depends as DependsParam


def add_router(
    app: FastAPI,
    router: APIRouter,
    *,
    dependencies: Sequence[DependsParam] = (),
    responses: dict[int | str, dict[str, Any]] | None = None,
) -> None:
    """``app.include_router(router, dependencies=..., responses=...)``, cheaper when both are
    empty.

    FastAPI (0.165) builds the routes of an included router again for each app, at its first
    request (each parameter's model: ~0.1 s of CPU an app, most of a test's new app). A router
    of a module was built once, at import, and its routes hold nothing of an app, so without
    dependencies or responses to add, the app takes those routes as they are; with them (reads
    that need a key) the router is included as before.
    """
    if dependencies or responses:
        app.include_router(router, dependencies=list(dependencies), responses=responses)
        return
    app.router.routes.extend(router.routes)
