"""Access control: API keys for changing (and, optionally, reading) the library.

With ``MOCAP_API_KEY`` set, the routes that change the library (``POST /clips``, ``PATCH`` and
``DELETE /clips/{id}``) need one of the configured keys, sent as ``Authorization: Bearer <key>``
or ``X-API-Key: <key>``; with ``MOCAP_REQUIRE_KEY_FOR_READS`` the reading routes need one too
(``/health`` and the docs stay open). No key sent: 401; a key that is not configured: 403 —
both in the one error shape. Keys are compared in constant time (:func:`hmac.compare_digest`,
against every configured key) and never logged: request logs carry no headers, and the
settings hold the key as a ``SecretStr``.

Without a configured key every route is open, and the service says so at start-up.
"""

from __future__ import annotations

import hmac
import logging
from typing import Annotated

from fastapi import Depends, Request, Security
from fastapi.params import Depends as DependsParam
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer

from app.config import Settings
from app.errors import Forbidden, Unauthorized

log = logging.getLogger(__name__)

API_KEY_HEADER = "X-API-Key"

# Declared as security schemes so the OpenAPI schema (and /docs' "Authorize" button) shows
# them; the checks below read the headers themselves, to tell a missing key from a wrong one.
bearer_scheme = HTTPBearer(
    auto_error=False,
    scheme_name="BearerKey",
    description="`Authorization: Bearer <key>` with a key of MOCAP_API_KEY.",
)
api_key_scheme = APIKeyHeader(
    name=API_KEY_HEADER,
    auto_error=False,
    scheme_name="ApiKeyHeader",
    description="`X-API-Key: <key>` with a key of MOCAP_API_KEY.",
)

BearerCredentials = Annotated[HTTPAuthorizationCredentials | None, Security(bearer_scheme)]
HeaderKey = Annotated[str | None, Security(api_key_scheme)]


def presented_keys(request: Request) -> list[bytes]:
    """The keys a request carries (Authorization Bearer and/or X-API-Key), as raw bytes."""
    keys = []
    authorization = request.headers.get("authorization")
    if authorization is not None:
        scheme, _, value = authorization.strip().partition(" ")
        if scheme.lower() != "bearer" or not value.strip():
            raise Unauthorized(
                "the Authorization header must be 'Bearer <API key>' (or send 'X-API-Key')"
            )
        keys.append(value.strip().encode("latin-1"))  # header bytes as sent
    header = request.headers.get(API_KEY_HEADER)
    if header is not None and header.strip():
        keys.append(header.strip().encode("latin-1"))
    return keys


def key_is_valid(key: bytes, configured: tuple[bytes, ...]) -> bool:
    """Whether ``key`` is one of ``configured``, in time independent of where they differ."""
    valid = False
    for candidate in configured:  # no early exit: every key is compared
        valid |= hmac.compare_digest(key, candidate)
    return valid


def check_key(request: Request, settings: Settings, action: str) -> None:
    """Raise 401 (no key) or 403 (wrong key) unless the request carries a configured key."""
    configured = settings.api_keys
    if not configured:
        return
    keys = presented_keys(request)
    if not keys:
        raise Unauthorized(
            f"missing API key: {action} needs 'Authorization: Bearer <key>' or "
            f"'{API_KEY_HEADER}: <key>'"
        )
    results = [key_is_valid(key, configured) for key in keys]
    if not any(results):
        raise Forbidden(f"the API key is not valid for {action}")


def _settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def require_write_key(request: Request, _bearer: BearerCredentials, _header: HeaderKey) -> None:
    """Dependency of the routes that change the library."""
    check_key(request, _settings(request), "changing the library")


def require_read_key(request: Request, _bearer: BearerCredentials, _header: HeaderKey) -> None:
    """Dependency of the reading routes when ``MOCAP_REQUIRE_KEY_FOR_READS`` is on."""
    settings = _settings(request)
    if settings.require_key_for_reads:
        check_key(request, settings, "reading the library")


WriteAccess = Depends(require_write_key)


def read_dependencies(settings: Settings) -> list[DependsParam]:
    """Dependencies for the reading routers: the key check only when reads need a key (so
    the OpenAPI schema declares security exactly where it is enforced)."""
    return [Depends(require_read_key)] if settings.require_key_for_reads else []


def log_access_policy(settings: Settings) -> None:
    """Say at start-up who may change (and read) the library, never printing a key."""
    count = len(settings.api_keys)
    if not count:
        log.warning("no API key configured: anyone can change the library (set MOCAP_API_KEY)")
        return
    reads = "reading and changing" if settings.require_key_for_reads else "changing"
    log.info(
        "API key required for %s the library (%d key%s configured)",
        reads,
        count,
        "" if count == 1 else "s",
    )
