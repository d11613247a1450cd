"""What is checked on a request's head, before a byte of its body is read.

:class:`RequestGuard` is pure ASGI middleware that finds the route a request goes to and, in
this order:

1. **Host** (DNS rebinding): the ``Host`` header must name this server — ``localhost``, an IP
   address, the address it binds to (``MOCAP_HOST``) or a name of ``MOCAP_ALLOWED_HOSTS`` —
   else 400 ``host_not_allowed``. A page whose name an attacker re-points at a local install
   is same-origin for the browser; only the name it puts in ``Host`` gives it away. An IP
   address cannot be re-pointed, so it is always accepted. ``/health`` skips this check
   (probes address replicas by whatever name they use).
2. **Cross-site writes**: a request with an unsafe method (POST, PUT, PATCH, DELETE) whose
   ``Origin`` is another origin than the one the request is addressed to (or ``null``), or,
   without ``Origin``, whose ``Sec-Fetch-Site`` says another site, is refused with 403
   ``cross_site_request`` — unless ``MOCAP_CORS_ORIGINS`` lists that origin. Clients that are
   not browsers send neither header and are not affected.
3. **API key** for the route's :class:`Access` level (401 / 403, :func:`app.api.auth.check_key`).
4. **Body size**: a route that takes a JSON body accepts at most :data:`MAX_JSON_BODY_BYTES`
   (413); uploads are bounded by ``MOCAP_MAX_UPLOAD_BYTES`` (:class:`app.api.limits.BodySizeLimit`).
5. **Heavy requests per client**: a request to a heavy route without a valid API key counts
   against its client address; past ``MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT`` in progress at
   once it gets 429 with ``Retry-After`` (:class:`ClientSlots`). This bounds what one client
   can take; the service-wide bound on concurrent describes is separate
   (:mod:`app.api.limits`).

So an anonymous 50 MB upload to a keyed server is answered 401 as soon as its head arrives.
The levels come from the operations of the application's own OpenAPI schema
(:func:`operation_access`): a new route is covered by the rule it falls under without being
listed here. Building that schema takes 0.3-1 s, so apps with the same routes share one table
(:func:`shared_access_table`).
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from fastapi import FastAPI
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Receive, Scope, Send

from app.api.auth import HEAVY_ROLE, WRITE_ROLE, check_key, has_valid_key
from app.api.errors import error_responses, response_for
from app.api.limits import BodySizeLimit
from app.config import Settings
from app.errors import CrossSiteRequest, HostNotAllowed, MocapError, TooManyRequests

# JSON bodies here carry a clip's name, label list, source and licence (tens of kilobytes at most);
# parsed into Python objects a JSON body takes ~13x its size, so it gets its own small cap.
MAX_JSON_BODY_BYTES = 1024 * 1024

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS", "TRACE"})
# Reading routes that do heavy work: they describe stored files (moments by a stored clip),
# convert them (a download with ``format``/``start``/``end``), or compute over the whole
# library (the map).
HEAVY_ROUTES = frozenset({("GET", "/map"), ("GET", "/search/moments")})
HEAVY_WITH_QUERY = {("GET", "/clips/{clip_id}/file"): frozenset({"format", "start", "end"})}
OPEN_PATHS = frozenset({"/health"})
LOCAL_NAMES = frozenset({"localhost"})
WILDCARD_ADDRESSES = frozenset({"", "0.0.0.0", "::"})
KNOWN_HOSTS = 256  # Host values whose check is remembered (see check_host)


class Access(IntEnum):
    """What a route does, in rising order of what it may need."""

    OPEN = 0  # /health, the docs, the web page and its files
    READ = 1  # reading the library: MOCAP_REQUIRE_KEY_FOR_READS
    HEAVY = 2  # parses a body or does heavy work: MOCAP_REQUIRE_KEY_FOR_HEAVY
    WRITE = 3  # changes the library: MOCAP_API_KEY


@dataclass(frozen=True)
class RouteAccess:
    level: Access
    heavy: bool = False  # parses an upload or does heavy work (limited per client)
    heavy_with: frozenset[str] = frozenset()  # query parameters that make the request heavy
    json_body: bool = False  # takes a body that is not a multipart upload

    def for_query(self, query_string: bytes) -> RouteAccess:
        """The access of one request: heavy if it gives a parameter of ``heavy_with``."""
        if self.heavy_with and not self.heavy:
            given = {k for k, v in parse_qsl(query_string.decode("latin-1")) if v.strip()}
            if given & self.heavy_with:
                level = max(self.level, Access.HEAVY)
                return RouteAccess(level, heavy=True, json_body=self.json_body)
        return self


def _roles(operation: dict[str, Any]) -> set[str]:
    return {
        role
        for requirement in operation.get("security", ())
        for r in requirement.values()
        for role in r
    }


def operation_access(method: str, path: str, operation: dict[str, Any]) -> RouteAccess:
    """The access of one operation of the OpenAPI schema, from what it is.

    Heavy: it parses an upload (a multipart body), is a POST, PUT, PATCH or DELETE that is
    not a write (a search by file, a preview, an export: nothing else is sent that way), or is
    listed in :data:`HEAVY_ROUTES`. Level: a write declares the ``write`` role
    (:data:`app.api.auth.WriteAccess`); ``/health`` is open; a heavy operation is HEAVY; the
    rest READ. (Routes outside the schema — the docs, the page, static files — are open.)"""
    body = operation.get("requestBody")
    upload = body is not None and "multipart/form-data" in body.get("content", {})
    json_body = body is not None and not upload
    write = WRITE_ROLE in _roles(operation)
    unsafe = method not in SAFE_METHODS
    heavy = upload or (unsafe and not write) or (method, path) in HEAVY_ROUTES
    heavy_with = HEAVY_WITH_QUERY.get((method, path), frozenset())
    if write:
        level = Access.WRITE
    elif path in OPEN_PATHS:
        return RouteAccess(Access.OPEN)
    else:
        level = Access.HEAVY if heavy else Access.READ
    return RouteAccess(level, heavy=heavy, heavy_with=heavy_with, json_body=json_body)


HTTP_METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")


@dataclass(frozen=True)
class AccessTable:
    """Every operation of the schema: literal paths by name, those with parameters by pattern."""

    literal: dict[tuple[str, str], RouteAccess]
    parametric: list[tuple[str, re.Pattern[str], str, RouteAccess]]  # method, pattern, path

    @classmethod
    def of(cls, schema: dict[str, Any]) -> AccessTable:
        literal = {}
        parametric = []
        for path, item in schema.get("paths", {}).items():
            for method in HTTP_METHODS:
                if method not in item:
                    continue
                access = operation_access(method.upper(), path, item[method])
                if "{" in path:
                    pattern = re.compile(re.sub(r"\\\{[^/]*?\\\}", "[^/]+", re.escape(path)) + "$")
                    parametric.append((method.upper(), pattern, path, access))
                else:
                    literal[method.upper(), path] = access
        return cls(literal, parametric)

    def find(self, method: str, path: str) -> tuple[str, RouteAccess]:
        """The operation's path pattern and access; ``("", OPEN)`` when none matches (the
        router answers 404 or 405 without reading a body). HEAD is answered by GET routes."""
        method = "GET" if method == "HEAD" else method
        access = self.literal.get((method, path))
        if access is not None:
            return path, access
        for wanted, pattern, route_path, access in self.parametric:
            if wanted == method and pattern.match(path):
                return route_path, access
        return "", RouteAccess(Access.OPEN)


# Access tables by the routes they were built for (see :func:`shared_access_table`).
_SHARED_TABLES: dict[Hashable, AccessTable] = {}


def shared_access_table(routes_key: Hashable, schema: Callable[[], dict[str, Any]]) -> AccessTable:
    """The access table of the apps whose routes ``routes_key`` names, built from ``schema``
    (one such app's OpenAPI schema) the first time. Sound because a level depends only on the
    operations (method, path, body, declared write role), never on the settings: the key
    must name every route. The test suite builds hundreds of apps with the same routes; a
    server builds one per worker."""
    table = _SHARED_TABLES.get(routes_key)
    if table is None:
        table = _SHARED_TABLES.setdefault(routes_key, AccessTable.of(schema()))
    return table


def required_level(settings: Settings) -> Access | None:
    """The lowest level that needs an API key under ``settings`` (None: no key configured)."""
    if not settings.api_keys:
        return None
    if settings.require_key_for_reads:
        return Access.READ
    if settings.require_key_for_heavy:
        return Access.HEAVY
    return Access.WRITE


ACTIONS = {
    Access.READ: "reading the library",
    Access.HEAVY: "this request (heavy work: MOCAP_REQUIRE_KEY_FOR_HEAVY)",
    Access.WRITE: "changing the library",
}


# -- Host and Origin --------------------------------------------------------------------------


def split_host(value: str) -> tuple[str, int | None]:
    """``"Example.com:8000"`` -> ``("example.com", 8000)``; ``"[::1]"`` -> ``("::1", None)``.
    A port that is not a number gives ``-1`` (matches nothing)."""
    value = value.strip().lower()
    if value.startswith("["):
        name, _, rest = value[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ""
    elif value.count(":") == 1:
        name, _, port_text = value.partition(":")
    else:
        name, port_text = value, ""
    if not port_text:
        return name.rstrip("."), None
    return name.rstrip("."), int(port_text) if port_text.isdigit() else -1


def is_ip_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def allowed_host_names(settings: Settings) -> frozenset[str]:
    """The names (besides IP addresses) a request's ``Host`` may carry."""
    names = set(LOCAL_NAMES) | {name.strip().lower().rstrip(".") for name in settings.allowed_hosts}
    if settings.host not in WILDCARD_ADDRESSES:
        names.add(split_host(settings.host)[0])
    return frozenset(names)


DEFAULT_PORTS = {"http": 80, "https": 443}


def same_origin(origin: str, host: str) -> bool:
    """Whether the browser origin ``origin`` (``scheme://name[:port]``) is the server the
    request is addressed to (its ``Host``). Without a port in ``Host`` the client used its
    scheme's default port, as it did when ``Origin`` has none."""
    try:
        parts = urlsplit(origin)
        origin_port = parts.port or DEFAULT_PORTS.get(parts.scheme)
    except ValueError:
        return False
    if parts.hostname is None or origin_port is None:
        return False
    name, port = split_host(host)
    if name != parts.hostname.rstrip("."):
        return False
    return (
        port == origin_port if port is not None else origin_port == DEFAULT_PORTS.get(parts.scheme)
    )


def check_host(
    headers: Headers, allowed: frozenset[str], known: dict[str, bool] | None = None
) -> None:
    """Refuse a request whose ``Host`` names none of ``allowed`` (see the module docstring).
    ``known``: the answers for the ``Host`` values seen before (a client sends the same
    one every time; parsing it, an IP address mostly, was a tenth of the guard's time)."""
    host = headers.get("host")
    if host is None or "*" in allowed:  # HTTP/1.0 without Host: not a browser
        return
    if known is not None and known.get(host):
        return
    name, _port = split_host(host)
    if name in allowed or is_ip_address(name):
        if known is not None:
            if len(known) >= KNOWN_HOSTS:  # Host is the client's to choose: keep it bounded
                known.clear()
            known[host] = True
        return
    raise HostNotAllowed(
        f"this server does not answer to the name {name[:100]!r} (Host header); add it to "
        "MOCAP_ALLOWED_HOSTS if users reach the service by that name"
    )


def check_same_site(headers: Headers, cors_origins: list[str]) -> None:
    """Refuse a browser's request that another site made (see the module docstring)."""
    origin = headers.get("origin")
    if origin is not None:
        if origin in cors_origins or "*" in cors_origins:
            return
        host = headers.get("host")
        if origin != "null" and host is not None and same_origin(origin, host):
            return
        raise CrossSiteRequest(
            f"a page of another site ({origin[:100]}) may not send this request; list its "
            "origin in MOCAP_CORS_ORIGINS to allow it"
        )
    site = headers.get("sec-fetch-site", "").lower()
    if site in ("cross-site", "same-site"):
        raise CrossSiteRequest(
            f"a page of another site may not send this request (Sec-Fetch-Site: {site})"
        )


# -- heavy requests per client ----------------------------------------------------------------


class ClientSlots:
    """How many heavy requests each client address has in progress (one event loop per
    process: no lock needed). An entry is dropped when its count is back to 0."""

    def __init__(self, per_client: int) -> None:
        self.per_client = per_client
        self.in_progress: dict[str, int] = {}

    def take(self, client: str) -> None:
        count = self.in_progress.get(client, 0)
        if count >= self.per_client:
            raise TooManyRequests(
                f"{count} heavy requests from this address are in progress, the most one "
                f"client may have without an API key (MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT); "
                "try again when one has finished"
            )
        self.in_progress[client] = count + 1

    def give_back(self, client: str) -> None:
        count = self.in_progress[client] - 1
        if count:
            self.in_progress[client] = count
        else:
            del self.in_progress[client]


class JsonBodyLimit(BodySizeLimit):
    """The body size limit of routes that take JSON (:data:`MAX_JSON_BODY_BYTES`)."""

    def _message(self) -> str:
        return f"JSON body over the {self.max_bytes}-byte limit of this route"


# -- the middleware ---------------------------------------------------------------------------


class RequestGuard:
    """Pure ASGI middleware; ``access_table`` gives the application's :class:`AccessTable`
    (asked for at the first request, when every route is registered)."""

    def __init__(
        self, app: ASGIApp, settings: Settings, access_table: Callable[[], AccessTable]
    ) -> None:
        self.app = app
        self.settings = settings
        self.access_table = access_table
        self.json_limited = JsonBodyLimit(app, MAX_JSON_BODY_BYTES)
        self.allowed_hosts = allowed_host_names(settings)
        self.known_hosts: dict[str, bool] = {}
        self.needs_key = required_level(settings)
        self.slots = ClientSlots(settings.max_heavy_requests_per_client)
        self._table: AccessTable | None = None
        self._by_path: dict[tuple[str, str], tuple[str, RouteAccess]] = {}

    def access_of(self, scope: Scope) -> tuple[str, RouteAccess]:
        """The operation's path pattern and access (cached per method and path)."""
        path: str = scope["path"]
        root = scope.get("root_path", "")
        if root and path.startswith(root):  # served under a prefix (uvicorn --root-path)
            path = path[len(root) :]
        key = (scope["method"], path)
        found = self._by_path.get(key)
        if found is None:
            if self._table is None:
                self._table = self.access_table()
            found = self._table.find(*key)
            if len(self._by_path) > 4096:  # paths carry ids: keep the cache bounded
                self._by_path.clear()
            self._by_path[key] = found
        return found

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = Headers(scope=scope)
        path, access = self.access_of(scope)
        client: str | None = None  # the address holding a heavy-request slot
        try:
            if path not in OPEN_PATHS:
                check_host(headers, self.allowed_hosts, self.known_hosts)
            if scope["method"] not in SAFE_METHODS:
                check_same_site(headers, self.settings.cors_origins)
            access = access.for_query(scope.get("query_string", b""))
            if self.needs_key is not None and access.level >= self.needs_key:
                check_key(headers, self.settings, ACTIONS[access.level])
            if access.heavy and not has_valid_key(headers, self.settings):
                client = scope["client"][0] if scope.get("client") else ""
                self.slots.take(client)
        except MocapError as error:
            await response_for(error)(scope, receive, send)
            return
        app: Callable[[Scope, Receive, Send], Any] = (
            self.json_limited if access.json_body else self.app
        )
        try:
            await app(scope, receive, send)
        finally:
            if client is not None:
                self.slots.give_back(client)


# -- what the OpenAPI schema says -------------------------------------------------------------


def document_access(app: FastAPI, settings: Settings) -> None:
    """Declare in the OpenAPI schema what :class:`RequestGuard` answers on each operation:
    403 ``cross_site_request`` on unsafe methods, 429 on heavy routes, and with
    ``MOCAP_REQUIRE_KEY_FOR_HEAVY`` the key (the ``heavy`` role, 401, 403) on heavy routes —
    optional where only some queries are heavy. Writes, and reads when they need a key,
    declare their role through their dependencies. The schema is post-processed once, when
    first built, so the routes (shared by every app built in a process) stay untouched."""
    build = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = build()
            _document(schema, required_level(settings))
        return app.openapi_schema  # type: ignore[return-value]

    app.openapi = openapi  # type: ignore[method-assign]


def _document(schema: dict[str, Any], needs_key: Access | None) -> None:
    for path, item in schema.get("paths", {}).items():
        for method in HTTP_METHODS:
            operation = item.get(method)
            if operation is None:
                continue
            access = operation_access(method.upper(), path, operation)
            if access.level == Access.OPEN:
                continue
            heavy = access.heavy or bool(access.heavy_with)
            statuses = [429] if heavy else []
            if method.upper() not in SAFE_METHODS:
                statuses.append(403)
            if heavy and access.level < Access.WRITE and needs_key == Access.HEAVY:
                statuses += [401, 403]
                optional: list[dict[str, list[str]]] = [{}] if access.level < Access.HEAVY else []
                operation["security"] = [
                    *optional,
                    {"BearerKey": [HEAVY_ROLE]},
                    {"ApiKeyHeader": [HEAVY_ROLE]},
                ]
            responses = operation.setdefault("responses", {})
            for status, response in error_responses(*statuses).items():
                responses.setdefault(str(status), _as_schema(response))


def _as_schema(response: dict[str, Any]) -> dict[str, Any]:
    """A route's ``responses=`` entry (with its pydantic ``model``) as OpenAPI JSON; every
    operation with an error response already put the model among the components."""
    model = response["model"]
    content = response["content"]["application/json"]
    return {
        "description": response["description"],
        "content": {
            "application/json": {
                "schema": {"$ref": f"#/components/schemas/{model.__name__}"},
                **content,
            }
        },
    }
