"""Worker processes that write FBX files with Blender's exporter (bpy), never in the server.

The parser pool's machinery (:class:`~app.services.parser_pool.ParserPool`: reused spawned
processes, one request at a time each, a time limit per request after which the worker is
killed, an address-space limit, a worker replaced after it crashes) with another worker
loop: this one imports Blender once (its start-up is the slow part, seconds), then writes
one FBX per request, each from an empty factory scene (:func:`app.motion.formats.fbx_writer.
write_fbx`), and retires after :data:`RETIRE_AFTER_EXPORTS` files or half its memory budget.

Where Blender's Python module is not installed (the ``fbx`` extra), nothing starts and
:meth:`ExportPool.write_fbx` raises :class:`~app.errors.FbxUnavailable` (501).
"""

from __future__ import annotations

import importlib.util
import os
import signal
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any, cast

from app.errors import ExportFailed, FbxUnavailable, InvalidInput, ParseError, UnreadableFile
from app.motion.model import Motion, ParseLimits
from app.services.parser_pool import ParserPool, serve_requests

if TYPE_CHECKING:
    from app.config import Settings

RETIRE_AFTER_EXPORTS = 16
WRITE_FBX = "fbx-write"
_UNAVAILABLE = "bpy-unavailable: "
INSTALL_HINT = (
    "format=fbx needs Blender's Python module (the `fbx` extra: bpy 4.4.0, CPython 3.11; "
    "`make install` installs it where a wheel exists)"
)


def fbx_unavailable_reason() -> str | None:
    """Why FBX files cannot be written here (without importing Blender), or ``None``."""
    if importlib.util.find_spec("bpy") is None:
        return f"{INSTALL_HINT}, which is not installed here; use format=glb or format=bvh"
    return None


def _import_blender() -> str | None:
    """Import bpy; the problem, or ``None``. The worker's stdout and stderr go nowhere from
    here on: Blender talks (a message about a numpy extension it does not use here, "export
    starting..." on every file), and the worker answers through its pipe only."""
    with open(os.devnull, "w") as devnull:
        os.dup2(devnull.fileno(), 1)
        os.dup2(devnull.fileno(), 2)
    try:
        import bpy  # noqa: F401

        import app.motion.formats.fbx_writer  # noqa: F401
    except Exception as error:
        return f"{type(error).__name__}: {error}"
    return None


def _export_answer(request: tuple[Any, ...], problem: str | None) -> tuple[Any, ...]:
    """The answer to ``(WRITE_FBX, (motion, metres_per_unit, name), None, limits)``: the FBX
    bytes, or why not (the answers of the parser pool's protocol)."""
    if problem is not None:
        return ("unreadable", f"{_UNAVAILABLE}{problem}")
    from app.motion.formats.fbx_writer import write_fbx

    motion, metres_per_unit, name = request[1]
    try:
        return ("ok", write_fbx(motion, metres_per_unit=metres_per_unit, name=name))
    except ValueError as error:
        return ("parse_error", str(error), None)
    except MemoryError:
        raise
    except Exception as error:  # the exporter failed on this motion
        return ("unreadable", f"Blender's FBX exporter failed ({type(error).__name__})")


def _export_worker_main(conn: Connection, memory_mb: int | None) -> None:
    """Import Blender, then answer FBX requests until the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    problem = _import_blender()
    serve_requests(
        conn,
        memory_mb,
        lambda request: _export_answer(request, problem),
        retire_after=RETIRE_AFTER_EXPORTS,
    )


class ExportPool(ParserPool):
    """Up to ``size`` warm Blender worker processes writing FBX files."""

    worker_main = staticmethod(_export_worker_main)
    kinds = (WRITE_FBX,)

    @classmethod
    def from_settings(cls, settings: Settings) -> ExportPool:
        """MOCAP_EXPORT_WORKERS, MOCAP_EXPORT_TIMEOUT_SECONDS, MOCAP_EXPORT_MEMORY_MB."""
        return cls(
            settings.export_workers,
            time_limit=settings.export_timeout_seconds,
            memory_mb=settings.export_memory_mb,
        )

    def write_fbx(self, motion: Motion, *, metres_per_unit: float, name: str) -> bytes:
        """The FBX bytes of ``motion`` (Y-up, in units of ``metres_per_unit`` metres).

        Raises
        ------
        FbxUnavailable
            Blender's Python module is not installed here or does not start.
        InvalidInput
            The motion cannot be written as FBX (a joint name too long for it).
        ExportFailed
            The worker crashed, ran out of time (MOCAP_EXPORT_TIMEOUT_SECONDS) or memory
            (MOCAP_EXPORT_MEMORY_MB).
        """
        reason = fbx_unavailable_reason()
        if reason is not None:
            raise FbxUnavailable(reason)
        try:
            data = self.parse(
                WRITE_FBX,
                cast(bytes, (motion, metres_per_unit, name)),
                animation=None,
                limits=ParseLimits(),
            )
        except ParseError as error:
            raise InvalidInput(f"format=fbx: {error.reason}") from None
        except UnreadableFile as error:
            raise self._failure(error.detail) from None
        return cast(bytes, data)

    def _failure(self, detail: str) -> FbxUnavailable | ExportFailed:
        """The pool's words for a lost worker, said about writing an FBX file."""
        if _UNAVAILABLE in detail:
            problem = detail.split(_UNAVAILABLE, 1)[1].rsplit("; the file cannot", 1)[0]
            return FbxUnavailable(f"{INSTALL_HINT}; it does not start here ({problem})")
        if "longer than" in detail:
            return ExportFailed(
                f"writing the FBX file took longer than {self.time_limit:g} s "
                "(MOCAP_EXPORT_TIMEOUT_SECONDS); try a shorter span or a lower fps"
            )
        if "more than" in detail and "MB" in detail:
            return ExportFailed(
                f"writing the FBX file needed more than {self.memory_mb} MB "
                "(MOCAP_EXPORT_MEMORY_MB); try a shorter span or a lower fps"
            )
        return ExportFailed(
            "the FBX export worker failed on this clip; try again, or format=glb"
            if "start" not in detail
            else f"the FBX export worker could not start ({detail})"
        )


__all__ = ["ExportPool", "fbx_unavailable_reason"]
