"""Domain exceptions of mocap-index.

One hierarchy for the whole service. Nothing here knows about HTTP: the API layer maps each
class to a status code in one table (``app/api/errors.py``). Every error carries a short
machine-readable ``code`` and a human ``detail`` message.
"""

from __future__ import annotations


class MocapError(Exception):
    """Base class of every error the service raises on purpose."""

    code = "error"

    def __init__(self, detail: str) -> None:
        super().__init__(detail)
        self.detail = detail


class InvalidInput(MocapError):
    """A request that is well-formed but asks for something impossible."""

    code = "invalid_input"


class ParseError(InvalidInput):
    """A motion file could not be read.

    Parameters
    ----------
    detail:
        What is wrong, in words a user can act on.
    line:
        1-based line number in the offending file, when one applies.
    source:
        Which uploaded part or file the error is about (e.g. ``"motion"`` or a file name).
    """

    code = "parse_error"

    def __init__(self, detail: str, *, line: int | None = None, source: str | None = None) -> None:
        self.line = line
        self.source = source
        where = []
        if source:
            where.append(source)
        if line is not None:
            where.append(f"line {line}")
        message = f"{', '.join(where)}: {detail}" if where else detail
        super().__init__(message)
        self.reason = detail

    def with_source(self, source: str) -> ParseError:
        """Return a copy that names the file it came from (keeps the line number)."""
        if self.source:
            return self
        return type(self)(self.reason, line=self.line, source=source)


class SkeletonMappingError(ParseError):
    """The skeleton lacks joints every descriptor needs (names the missing canonical joints)."""

    code = "unmappable_skeleton"


class UnknownAnimation(ParseError):
    """An FBX/glTF animation asked for by a name the file does not have (the detail lists
    the file's animations)."""

    code = "unknown_animation"


class NoAnimation(ParseError):
    """A rig with no animation: a skeleton (and maybe a mesh) that is read fine but holds no
    motion to describe (BVH ``Frames: 0`` or no MOTION section, an FBX/glTF without an
    animation or with only a zero-length one). Not a damaged file: it is usable as a target
    rig, just not as a clip."""

    code = "no_animation"


class UnreadableFile(InvalidInput):
    """A file whose reader crashed, hung or ran out of memory (in its worker process)."""

    code = "unreadable_file"


class LimitExceeded(InvalidInput):
    """Input over a configured limit (frames, joints, nesting depth, line length...)."""

    code = "limit_exceeded"


class MalformedRequest(MocapError):
    """A request body that is not what its ``Content-Type`` says: a multipart body cut before
    its closing boundary, a part header over the size limit, a broken boundary."""

    code = "bad_request"


class PayloadTooLarge(MocapError):
    """An upload larger than the configured maximum size."""

    code = "payload_too_large"


class UnsupportedMediaType(MocapError):
    """An upload of a kind the service does not read."""

    code = "unsupported_media_type"


class NotFound(MocapError):
    code = "not_found"


class NoStoredFile(NotFound):
    """A clip without uploaded files (a synthetic benchmark clip): nothing to download or draw."""

    code = "no_stored_file"

    def __init__(self, clip_id: int, kind: str) -> None:
        super().__init__(
            f"clip {clip_id} is a {kind} clip: it has no stored file to download or preview"
        )


class Unauthorized(MocapError):
    code = "unauthorized"


class Forbidden(MocapError):
    code = "forbidden"


class CrossSiteRequest(Forbidden):
    """A browser sent a request that changes something or does heavy work from a page of
    another site (its ``Origin`` or ``Sec-Fetch-Site`` says so)."""

    code = "cross_site_request"


class HostNotAllowed(MocapError):
    """The request is addressed (``Host``) to a name this server does not answer to: the
    mark of a DNS-rebinding page."""

    code = "host_not_allowed"


class TooManyRequests(MocapError):
    """One client has as many heavy requests in progress as it may; ``retry_after`` seconds
    is a fair wait before trying again."""

    code = "too_many_requests"
    retry_after = 1


class StorageUnavailable(MocapError):
    """The data directory or database cannot be written (disk full, read-only, locked)."""

    code = "storage_unavailable"


class DescriptorUnavailable(MocapError):
    """The query clip has no vector of the descriptor's current version (the descriptor is
    newer than the clip); ``mocap-index reindex`` computes it."""

    code = "descriptor_unavailable"


class DescriptorOutdated(DescriptorUnavailable):
    """Stored clips still hold vectors of an older version of the descriptor (a library
    written by an earlier release): a search under it would miss them, so it is refused
    until ``mocap-index reindex`` recomputes them."""

    code = "descriptor_outdated"


class MomentsOff(MocapError):
    """Moments search was asked of a library that keeps no windows (MOCAP_MOMENTS=false)."""

    code = "moments_off"


class DescribeTimeout(MocapError):
    """Describing an uploaded clip took longer than the configured request time limit."""

    code = "describe_timeout"


class ServiceBusy(MocapError):
    """Every slot for this kind of work is taken (describing uploads, reading FBX/glTF files)
    and none freed up in time: try again after ``retry_after`` seconds."""

    code = "busy"

    def __init__(self, detail: str, *, retry_after: int = 1) -> None:
        super().__init__(detail)
        self.retry_after = max(1, int(retry_after))


class FbxUnavailable(MocapError):
    """``format=fbx`` on a machine where Blender's Python module (the ``fbx`` extra) is not
    installed or cannot start: FBX files cannot be written here."""

    code = "fbx_unavailable"


class ExportFailed(MocapError):
    """An export worker crashed, ran out of time or memory writing a file."""

    code = "export_failed"
