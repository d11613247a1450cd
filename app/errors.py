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
        return ParseError(self.reason, line=self.line, source=source)


class SkeletonMappingError(ParseError):
    """The skeleton lacks joints every descriptor needs (names the missing canonical joints)."""

    code = "unmappable_skeleton"


class UnreadableFile(InvalidInput):
    """A file whose reader crashed, hung or ran out of memory (in its worker process)."""

    code = "unreadable_file"


class LimitExceeded(InvalidInput):
    """Input over a configured limit (frames, joints, nesting depth, line length...)."""

    code = "limit_exceeded"


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


class FbxUnavailable(MocapError):
    """``format=fbx`` on a machine where Blender's Python module (the ``fbx`` extra) is not
    installed or cannot start: FBX files cannot be written here."""

    code = "fbx_unavailable"


class ExportFailed(MocapError):
    """An export worker crashed, ran out of time or memory writing a file."""

    code = "export_failed"
