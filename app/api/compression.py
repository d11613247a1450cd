"""Compressed answers: gzip for JSON and the web UI's text files, for clients that accept it.

A search of 50 clips fetches 51 skeletons; gzip makes their JSON a quarter of its size and
the API's other JSON smaller too. Left alone: answers under :data:`MINIMUM_BYTES` (the
headers would cost more than the bytes saved), downloads (``application/octet-stream``, ZIP:
sent byte for byte, as stored) and what is compressed already (Starlette's list). Request
bodies are not touched: the service refuses compressed uploads (``app.api.limits``).
"""

from __future__ import annotations

from fastapi import FastAPI
from starlette.middleware.gzip import DEFAULT_EXCLUDED_CONTENT_TYPES, GZipMiddleware

MINIMUM_BYTES = 1024
LEVEL = 6  # zlib's default: level 9 costs twice the time for ~2 % less


def add_compression(app: FastAPI) -> None:
    """Compress ``app``'s larger answers (see the module docstring)."""
    app.add_middleware(
        GZipMiddleware,
        minimum_size=MINIMUM_BYTES,
        compresslevel=LEVEL,
        exclude_content_types=(*DEFAULT_EXCLUDED_CONTENT_TYPES, "application/octet-stream"),
    )
