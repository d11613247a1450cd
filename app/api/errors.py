"""The HTTP edge of errors: one table from domain exception to status, one JSON shape.

Every error response, ours or the framework's (validation, unknown route, wrong method), is
``{"error": "<code>", "detail": "<human message>"}``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.exc import OperationalError
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.errors import (
    DescribeTimeout,
    DescriptorUnavailable,
    ExportFailed,
    FbxUnavailable,
    Forbidden,
    HostNotAllowed,
    InvalidInput,
    MalformedRequest,
    MocapError,
    MomentsOff,
    NoAnimation,
    NotFound,
    PayloadTooLarge,
    ServiceBusy,
    StorageUnavailable,
    TooManyRequests,
    Unauthorized,
    UnsupportedMediaType,
)

log = logging.getLogger(__name__)

# THE table: domain exception class -> HTTP status. Subclasses inherit their base's status
# (ParseError, SkeletonMappingError and LimitExceeded are InvalidInput: 422).
STATUS_BY_ERROR: dict[type[MocapError], int] = {
    NoAnimation: 422,  # a rig without motion: readable, but not a clip
    InvalidInput: 422,
    NotFound: 404,
    PayloadTooLarge: 413,
    UnsupportedMediaType: 415,
    Unauthorized: 401,
    Forbidden: 403,
    HostNotAllowed: 400,
    MalformedRequest: 400,
    TooManyRequests: 429,
    DescriptorUnavailable: 409,
    MomentsOff: 409,
    StorageUnavailable: 503,
    DescribeTimeout: 503,
    ServiceBusy: 503,
    ExportFailed: 503,
    FbxUnavailable: 501,
    MocapError: 400,
}

# Codes for errors raised by the framework, by status. A bad parameter is ``invalid_input``
# whether FastAPI's validation or our own check finds it (``k=abc`` and ``k=0`` alike).
_FRAMEWORK_CODES = {
    413: PayloadTooLarge.code,
    415: UnsupportedMediaType.code,
    422: InvalidInput.code,
    500: "internal_error",
}


class ErrorResponse(BaseModel):
    """The body of every error response."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"error": "not_found", "detail": "no clip with id 42"}]}
    )

    error: str = Field(description="Machine-readable error code, e.g. `not_found`.")
    detail: str = Field(description="What went wrong, in words a person can act on.")


def status_for(error: MocapError) -> int:
    for cls in type(error).__mro__:
        if cls in STATUS_BY_ERROR:
            return STATUS_BY_ERROR[cls]
    return 500


def code_for_status(status: int) -> str:
    if status in _FRAMEWORK_CODES:
        return _FRAMEWORK_CODES[status]
    try:
        return HTTPStatus(status).phrase.lower().replace(" ", "_").replace("-", "_")
    except ValueError:
        return "error"


def error_json(
    status: int, code: str, detail: str, headers: Mapping[str, str] | None = None
) -> JSONResponse:
    return JSONResponse({"error": code, "detail": detail}, status_code=status, headers=headers)


def _location(loc: tuple[Any, ...]) -> str:
    # ("body", "file") -> "file"; ("query", "k") -> "query.k"
    parts = [str(p) for p in loc]
    if parts and parts[0] == "body":
        parts = parts[1:]
    return ".".join(parts) or "request"


def _message(error: Mapping[str, Any]) -> str:
    # pydantic's words for a text value where a file part belongs are its internals
    # ("Value error, Expected UploadFile, received: <class 'str'>"): say it in the API's.
    message = str(error.get("msg"))
    if "Expected UploadFile" in message:
        return "must be a file: a multipart part with a file name, not a text value"
    return message


def describe_validation_error(exc: RequestValidationError) -> str:
    return "; ".join(f"{_location(tuple(e.get('loc', ())))}: {_message(e)}" for e in exc.errors())


def _invalid_json(exc: RequestValidationError) -> str | None:
    """What is wrong with a body that is not JSON at all, or ``None`` (FastAPI reports it as
    a validation error at ``("body", <character>)``)."""
    for error in exc.errors():
        if error.get("type") == "json_invalid":
            loc = tuple(error.get("loc", ()))
            where = f" at character {loc[-1]}" if len(loc) > 1 else ""
            reason = (error.get("ctx") or {}).get("error")
            return f"body: not valid JSON{where}" + (f" ({reason})" if reason else "")
    return None


def response_for(error: MocapError) -> JSONResponse:
    """The error response of a domain error: its status from the table, the one shape, and
    ``WWW-Authenticate`` (401) or ``Retry-After`` (an error that says when to retry)."""
    status = status_for(error)
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else {}
    retry_after = getattr(error, "retry_after", None)
    if retry_after is not None:
        headers["Retry-After"] = str(retry_after)
    return error_json(status, error.code, error.detail, headers or None)


async def _on_domain_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, MocapError)
    if isinstance(exc, NoAnimation):
        # A rig is no clip, but it is what POST /rigs takes (there it is the rig, no error):
        # say where it is of use.
        return error_json(
            status_for(exc),
            exc.code,
            f"{exc.detail}; it can be a rig to retarget onto (POST /rigs)",
        )
    return response_for(exc)


async def _on_validation_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    invalid_json = _invalid_json(exc)
    if invalid_json is not None:  # malformed, like a body nested too deep to parse: 400
        return error_json(400, code_for_status(400), invalid_json)
    return error_json(422, InvalidInput.code, describe_validation_error(exc))


async def _on_http_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, StarletteHTTPException)
    detail = exc.detail if isinstance(exc.detail, str) else str(exc.detail)
    if exc.status_code == 404 and detail == "Not Found":
        detail = "no such route; see /docs for the API"
    return error_json(exc.status_code, code_for_status(exc.status_code), detail, exc.headers)


async def _on_database_error(_request: Request, exc: Exception) -> JSONResponse:
    # The database is unreachable, locked past the busy timeout, read-only or out of disk.
    log.error("database error: %s", exc)
    return error_json(503, StorageUnavailable.code, "the database is unavailable; try again")


async def _on_storage_error(_request: Request, exc: Exception) -> JSONResponse:
    # A file operation the services did not expect to fail (disk full, read-only or missing
    # data directory while saving an index, say): the database stays the source of truth.
    assert isinstance(exc, OSError)
    log.error("storage error: %s", exc)
    reason = exc.strerror or type(exc).__name__
    return error_json(
        503, StorageUnavailable.code, f"the data directory cannot be written: {reason}; try again"
    )


async def _on_unexpected_error(_request: Request, exc: Exception) -> JSONResponse:
    log.exception("unhandled error", exc_info=exc)
    return error_json(500, "internal_error", "internal error; the server log has the details")


def install_error_handlers(app: FastAPI) -> None:
    app.add_exception_handler(MocapError, _on_domain_error)
    app.add_exception_handler(RequestValidationError, _on_validation_error)
    app.add_exception_handler(StarletteHTTPException, _on_http_error)
    app.add_exception_handler(OperationalError, _on_database_error)
    app.add_exception_handler(OSError, _on_storage_error)
    app.add_exception_handler(Exception, _on_unexpected_error)


# -- OpenAPI documentation of the error responses ------------------------------------------

ERROR_EXAMPLES: dict[int, dict[str, tuple[str, str]]] = {
    400: {
        "bad_request": (
            "Malformed request",
            "multipart body: truncated: it ends after 8192 bytes, in part 1, without its "
            "closing boundary ('--<boundary>--')",
        ),
        "host_not_allowed": (
            "Request addressed to a name the server does not answer to",
            "this server does not answer to the name 'evil.example' (Host header); add it to "
            "MOCAP_ALLOWED_HOSTS if users reach the service by that name",
        ),
    },
    401: {"unauthorized": ("Missing or wrong API key", "missing API key")},
    403: {
        "forbidden": (
            "Wrong API key",
            "the API key in 'X-API-Key' is not valid for changing the library",
        ),
        "cross_site_request": (
            "Sent by a page of another site",
            "a page of another site (https://evil.example) may not send this request; list "
            "its origin in MOCAP_CORS_ORIGINS to allow it",
        ),
    },
    404: {
        "not_found": ("Unknown clip", "no clip with id 42"),
        "no_stored_file": (
            "Clip without a stored file",
            "clip 9 is a synthetic clip: it has no stored file to download or preview",
        ),
    },
    409: {
        "descriptor_unavailable": (
            "Clip lacks a current vector",
            "clip 7 has no 'motion' vector of version 2 yet; run `mocap-index reindex`",
        )
    },
    413: {
        "payload_too_large": (
            "Upload over the size limit",
            "request body over the 52428800-byte limit (MOCAP_MAX_UPLOAD_BYTES)",
        )
    },
    415: {
        "unsupported_media_type": (
            "Not a .bvh / .asf / .amc file",
            "field 'file': expected a .bvh file, got 'walk.fbx' (supported: .bvh as 'file', "
            "or .asf as 'skeleton' with .amc as 'motion')",
        )
    },
    422: {
        "parse_error": (
            "Unreadable motion file",
            "file 'walk.bvh', line 12: CHANNELS: 'x' is not a number",
        ),
        "unknown_animation": (
            "No animation of that name in the FBX/glTF file",
            "file 'robot.glb': animation: the file has no animation 'Run'; it has 'Dance', "
            "'Idle', 'Walk'",
        ),
        "no_animation": (
            "A rig with no animation",
            "file 'tpose.fbx': the file is a rig with no animation: a skeleton of 68 joints and "
            "only a zero-length animation ('Take 001', one instant), so there is no motion to "
            "describe; it can be a rig to retarget onto (POST /rigs)",
        ),
        "limit_exceeded": (
            "Over the frame or joint limit",
            "file 'long.bvh', line 9: 200000 frames, more than the limit of 100000",
        ),
        "invalid_input": (
            "Bad parameter or missing part",
            "query.k: Input should be a valid integer",
        ),
    },
    429: {
        "too_many_requests": (
            "Too many heavy requests from one client",
            "2 heavy requests from this address are in progress, the most one client may have "
            "without an API key (MOCAP_MAX_HEAVY_REQUESTS_PER_CLIENT); try again when one has "
            "finished",
        )
    },
    501: {
        "fbx_unavailable": (
            "FBX export not installed",
            "format=fbx needs Blender's Python module (the `fbx` extra, bpy 4.4.0), which is "
            "not installed here; use format=glb or format=bvh",
        )
    },
    503: {
        "export_failed": (
            "Export worker failed",
            "writing the FBX file took longer than 60 s (MOCAP_EXPORT_TIMEOUT_SECONDS)",
        ),
        "storage_unavailable": (
            "Database or disk unavailable",
            "cannot store the uploaded file: No space left on device",
        ),
        "describe_timeout": (
            "Describing the upload took too long",
            "describing the clip took longer than the 30-second limit "
            "(MOCAP_DESCRIBE_TIMEOUT_SECONDS); the server is busy or the clip too long",
        ),
    },
}


def error_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route: the error model with examples for each status."""
    responses: dict[int | str, dict[str, Any]] = {}
    for status in statuses:
        examples = {
            code: {"summary": summary, "value": {"error": code, "detail": detail}}
            for code, (summary, detail) in ERROR_EXAMPLES[status].items()
        }
        responses[status] = {
            "model": ErrorResponse,
            "description": HTTPStatus(status).phrase,
            "content": {"application/json": {"examples": examples}},
        }
    return responses
