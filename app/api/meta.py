"""/descriptors and /health.

``router`` (``/health``, ``/``) is always open, so health checks need no key; ``read_router``
(``/descriptors``) is guarded like the other reading routes when reads need a key.
"""

from __future__ import annotations

from fastapi import APIRouter

from app.api.deps import LibraryDep
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute
from app.api.schemas import DescriptorList, DescriptorOut, Health, IndexHealth

router = APIRouter(tags=["service"], route_class=CheckedQueryRoute)
read_router = APIRouter(tags=["service"], route_class=CheckedQueryRoute)


@read_router.get("/descriptors", summary="Available descriptors")
def list_descriptors(library: LibraryDep) -> DescriptorList:
    """Every descriptor a search can use, with its dimension, version and what it measures."""
    return DescriptorList(
        default=library.default_descriptor,
        descriptors=[DescriptorOut.of(info) for info in library.descriptors.values()],
    )


@router.get(
    "/health", summary="Liveness, clip count and index sizes", responses=error_responses(503)
)
def health(library: LibraryDep) -> Health:
    """The service is up and its database answers; how many clips and indexed vectors.

    The indexes first take in clips another process (`mocap-index import`, another replica)
    stored or deleted, as a search does — so a health-checked replica stays current;
    `missing` counts the clips without a current vector in the database, which no search can
    find until `mocap-index reindex`."""
    library.refresh()
    clips, stored = library.vector_counts()
    indexes = {}
    for name, info in library.descriptors.items():
        indexes[name] = IndexHealth(
            size=library.indexes[name].size,
            dimension=info.dimension,
            version=info.version,
            missing=max(clips - stored[name], 0),
        )
    return Health(status="ok", clips=clips, indexes=indexes)
