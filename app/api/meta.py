"""/descriptors and /health.

``router`` (``/health``, ``/``) is always open, so health checks need no key; ``read_router``
(``/descriptors``) is guarded like the other reading routes when reads need a key.
"""

from __future__ import annotations

import anyio
from fastapi import APIRouter, Request

from app.api.deps import LibraryDep
from app.api.errors import error_responses
from app.api.query_check import CheckedQueryRoute
from app.api.schemas import DescriptorList, DescriptorOut, Health, IndexHealth
from app.services.library import Library

router = APIRouter(tags=["service"], route_class=CheckedQueryRoute)
read_router = APIRouter(tags=["service"], route_class=CheckedQueryRoute)

# /health has threads of its own: when uploads and searches hold every thread of the
# default pool (40), a load balancer's health check must still be answered at once.
HEALTH_THREADS = anyio.CapacityLimiter(2)


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
async def health(request: Request) -> Health:
    """The service is up and its database answers; how many clips and indexed vectors.

    The indexes first take in clips another process (`mocap-index import`, another replica)
    stored or deleted, as a search does — so a health-checked replica stays current;
    `missing` counts the clips without a current vector in the database, which no search can
    find until `mocap-index reindex`."""
    library: Library = request.app.state.library
    return await anyio.to_thread.run_sync(_health, library, limiter=HEALTH_THREADS)


def _health(library: Library) -> Health:
    library.refresh_now()  # not a hot route: no background refresher's delay
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
