"""The app with the UI, for the browser tests' server: ``uvicorn --factory
tests.ui.serve:create_ui_app`` (settings from ``MOCAP_*`` variables)."""

from __future__ import annotations

from fastapi import FastAPI

from app.api.ui import mount_ui
from app.main import create_app


def create_ui_app() -> FastAPI:
    app = create_app()
    mount_ui(app)  # idempotent: harmless once create_app mounts the UI itself
    return app
