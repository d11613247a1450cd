"""/exports: many clips at once, as one streamed ZIP with a manifest."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Literal

from fastapi import APIRouter
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, ConfigDict, Field

from app.api.deps import LibraryDep
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute

router = APIRouter(prefix="/exports", tags=["exports"], route_class=CheckedQueryRoute)


class ClipSpan(BaseModel):
    """One clip, or a span of it (a moment)."""

    model_config = ConfigDict(extra="forbid")

    id: int = Field(description="Clip id.")
    start: float | None = Field(default=None, description="Cut from here, seconds.")
    end: float | None = Field(default=None, description="Cut up to here (exclusive), seconds.")


class SearchQuery(BaseModel):
    """The query of `GET /search`: its hits are exported (not the query clip)."""

    model_config = ConfigDict(extra="forbid")

    clip: int = Field(description="Id of the query clip.")
    k: int = Field(default=10, description="How many neighbours, 1 to MOCAP_MAX_K.")
    descriptor: str | None = Field(default=None, description="Descriptor; default `motion`.")
    label: list[str] | None = Field(default=None, description="Only clips carrying these.")


class ExportRequest(BaseModel):
    """Which clips (exactly one of `clips`, `label`, `search`) and the download options of
    `GET /clips/{id}/file`."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"label": ["walk"], "format": "fbx", "rig": 1, "root": "in-place"}]
        },
    )

    clips: list[int | ClipSpan] | None = Field(
        default=None, description="Clip ids, or `{id, start, end}` for a span of a clip."
    )
    label: list[str] | None = Field(default=None, description="Every clip carrying all these.")
    search: SearchQuery | None = Field(default=None, description="The hits of a search.")
    format: Literal["bvh", "fbx", "glb"] = Field(default="bvh", description="File format.")
    units: Literal["cm", "m", "in"] | None = Field(default=None, description="BVH/FBX units.")
    fps: float | None = Field(default=None, description="Frame rate (1 to 1000).")
    root: Literal["keep", "in-place", "extract"] = Field(default="keep", description="Root.")
    rig: int | None = Field(default=None, description="Retarget onto this rig.")


@router.post(
    "",
    summary="Download many clips as one ZIP",
    response_class=StreamingResponse,
    responses={
        200: {
            "description": "A ZIP of `<clip name>.<format>` files (names made unique) and "
            "`manifest.csv` (id, name, file, source, licence, frames, fps, duration, options, "
            "error: a clip that could not be exported has its reason there and no file).",
            "content": {"application/zip": {}},
        },
        **error_responses(400, 404, 422, 501, 503),
    },
)
def create_export(body: ExportRequest, library: LibraryDep) -> StreamingResponse:
    """Export the clips named by `clips`, `label` or `search` with the options of a single
    download, streamed as each file is written. At most MOCAP_MAX_EXPORT_CLIPS clips (422
    beyond, saying how many)."""
    # Imported here, not at start-up: the export pipeline (retargeting and the writers) is
    # ~70 ms of a worker's start for a route few requests take.
    from app.services.export import Exporter, ExportOptions, export_items, export_zip

    options = ExportOptions(
        format=body.format, units=body.units, fps=body.fps, root=body.root, rig=body.rig
    )
    exporter = Exporter(library, options)  # checks the options and loads the rig, or 4xx
    spans = None
    if body.clips is not None:
        spans = [
            (c, None, None) if isinstance(c, int) else (c.id, c.start, c.end) for c in body.clips
        ]
    search = None
    if body.search is not None:
        q = body.search
        search = (q.clip, q.descriptor, q.k, q.label)
    items = export_items(library, clips=spans, labels=body.label, search=search)
    if body.format == "fbx" and library.exporters is not None:
        from app.services.export_pool import fbx_unavailable_reason

        reason = fbx_unavailable_reason()
        if reason is not None:
            from app.errors import FbxUnavailable

            raise FbxUnavailable(reason)
    stamp = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    return StreamingResponse(
        export_zip(exporter, items),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="mocap-export-{stamp}.zip"'},
    )
