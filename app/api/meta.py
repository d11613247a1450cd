"""/descriptors and /health.

``router`` (``/health``, ``/``) is always open, so health checks need no key; ``read_router``
(``/descriptors``) is guarded like the other reading routes when reads need a key.
"""

from __future__ import annotations

from fastapi import APIRouter

from app.api.deps import LibraryDep
from app.api.errors import error_responses
from app.api.schemas import DescriptorList, DescriptorOut, Health, IndexHealth
from app.services.library import DEFAULT_DESCRIPTOR

router = APIRouter(tags=["service"])
read_router = APIRouter(tags=["service"])


@read_router.get("/descriptors", summary="Available descriptors")
def list_descriptors(library: LibraryDep) -> DescriptorList:
    """Every descriptor a search can use, with its dimension, version and what it measures."""
    return DescriptorList(
        default=DEFAULT_DESCRIPTOR,
        descriptors=[DescriptorOut.of(info) for info in library.descriptors.values()],
    )


@router.get(
    "/health", summary="Liveness, clip count and index sizes", responses=error_responses(503)
)
def health(library: LibraryDep) -> Health:
    """The service is up and its database answers; how many clips and indexed vectors."""
    library.refresh()  # index sizes as of now (and a health-checked replica stays current)
    clips = library.clip_count()
    indexes = {}
    for name, info in library.descriptors.items():
        size = library.indexes[name].size
        indexes[name] = IndexHealth(
            size=size, dimension=info.dimension, version=info.version, missing=max(clips - size, 0)
        )
    return Health(status="ok", clips=clips, indexes=indexes)
