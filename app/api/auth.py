"""Access control: API keys for changing (and, optionally, reading) the library.

With ``MOCAP_API_KEY`` set, the routes that change the library (``POST /clips``, ``PATCH`` and
``DELETE /clips/{id}``, ``DELETE /clips``) need one of the configured keys, sent as
``Authorization: Bearer <key>`` or ``X-API-Key: <key>``; with ``MOCAP_REQUIRE_KEY_FOR_HEAVY``
the routes that parse an upload or do heavy work need one too, with
``MOCAP_REQUIRE_KEY_FOR_READS`` every reading route (``/health`` and the docs stay open).
No key sent: 401; a key that is not configured: 403 — both in the one error shape. One
valid key is enough and every key sent must be valid (:func:`check_key`). Keys are compared
in constant time (:func:`hmac.compare_digest`, against every configured key) and never
logged: request logs carry no headers, and the settings hold the key as a ``SecretStr``.

The check runs on the request's head, before its body is read
(:class:`app.api.guard.RequestGuard`); the dependencies below declare the security schemes in
the OpenAPI schema and check again where they are declared.

Without a configured key every route is open, and the service says so at start-up.
"""

from __future__ import annotations

import hmac
import logging
from typing import Annotated

from fastapi import Request, Security
from fastapi.params import Depends as DependsParam
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette.datastructures import Headers

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


def presented_keys(headers: Headers) -> list[tuple[str, bytes]]:
    """The keys a request carries, each with where it came from, as raw bytes.

    Every ``Authorization: Bearer <key>`` and every ``X-API-Key`` header is a key. An
    ``Authorization`` header of another scheme (``Basic``, ``Digest``...) belongs to a proxy or
    a browser login in front of the service, not to it: it is no key and is ignored. A blank
    value is no key either."""
    keys = []
    for authorization in headers.getlist("authorization"):
        scheme, _, value = authorization.strip().partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            keys.append(("Authorization: Bearer", value.strip().encode("latin-1")))
    for header in headers.getlist(API_KEY_HEADER):
        if header.strip():
            keys.append((API_KEY_HEADER, header.strip().encode("latin-1")))
    return keys


def key_is_valid(key: bytes, configured: tuple[bytes, ...]) -> bool:
    """Whether ``key`` is one of ``configured``, in time independent of where they differ."""
    valid = False
    for candidate in configured:  # no early exit: every key is compared
        valid |= hmac.compare_digest(key, candidate)
    return valid


def check_key(headers: Headers, settings: Settings, action: str) -> None:
    """Raise 401 (no key) or 403 (a wrong key) unless the request carries a configured key.

    The rule: one valid key, in either place, is enough, and every key the request carries
    must be valid — a wrong key is refused even beside a valid one, never silently
    overridden (a client sending two different keys is misconfigured, and should hear it)."""
    configured = settings.api_keys
    if not configured:
        return
    keys = presented_keys(headers)
    if not keys:
        # Never echo the header: a client may have put the key itself there.
        other = (
            " (the Authorization header sent is not 'Bearer <key>': other schemes belong to a "
            "proxy in front, not to this service)"
            if "authorization" in headers
            else ""
        )
        raise Unauthorized(
            f"missing API key: {action} needs 'Authorization: Bearer <key>' or "
            f"'{API_KEY_HEADER}: <key>'{other}"
        )
    wrong = [place for place, key in keys if not key_is_valid(key, configured)]
    if wrong:
        beside = (
            "; another header carries a valid key, but a wrong key is never overridden: "
            "send only the right one"
            if len(wrong) < len(keys)
            else ""
        )
        raise Forbidden(f"the API key in '{wrong[0]}' is not valid for {action}{beside}")


def has_valid_key(headers: Headers, settings: Settings) -> bool:
    """Whether the request carries keys and every one is configured (see :func:`check_key`)."""
    configured = settings.api_keys
    keys = presented_keys(headers) if configured else []
    return bool(keys) and all([key_is_valid(key, configured) for _place, key in keys])


def _settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def require_write_key(request: Request, _bearer: BearerCredentials, _header: HeaderKey) -> None:
    """Dependency of the routes that change the library."""
    check_key(request.headers, _settings(request), "changing the library")


def require_read_key(request: Request, _bearer: BearerCredentials, _header: HeaderKey) -> None:
    """Dependency of the reading routes when ``MOCAP_REQUIRE_KEY_FOR_READS`` is on."""
    settings = _settings(request)
    if settings.require_key_for_reads:
        check_key(request.headers, settings, "reading the library")


# The role each declares (OpenAPI 3.1 security requirements may name roles for any scheme):
# the schema says which operations change the library, and the request guard reads it there.
WRITE_ROLE, READ_ROLE, HEAVY_ROLE = "write", "read", "heavy"
WriteAccess = Security(require_write_key, scopes=[WRITE_ROLE])


def read_dependencies(settings: Settings) -> list[DependsParam]:
    """Dependencies for the reading routers: the key check only when reads need a key (so
    the OpenAPI schema declares security exactly where it is enforced)."""
    return (
        [Security(require_read_key, scopes=[READ_ROLE])] if settings.require_key_for_reads else []
    )


def log_access_policy(settings: Settings) -> None:
    """Say at start-up who may change (and read) the library, never printing a key."""
    count = len(settings.api_keys)
    if not count:
        log.warning("no API key configured: anyone can change the library (set MOCAP_API_KEY)")
        return
    reads = (
        "reading and changing"
        if settings.require_key_for_reads
        else "heavy requests and changing"
        if settings.require_key_for_heavy
        else "changing"
    )
    log.info(
        "API key required for %s the library (%d key%s configured)",
        reads,
        count,
        "" if count == 1 else "s",
    )
