"""Unknown query parameters are refused, on every route, as a bad value is.

``GET /clips?name=walk`` used to list every clip: the misspelt filter was silently ignored,
which reads as "no clip is named walk" or "the filter works". Every API route now answers
422 ``invalid_input`` naming the parameter it does not take and those it does.

Routers take :class:`CheckedQueryRoute` as their ``route_class``: the check runs in the
route's handler, before its parameters are read — a parse of the query string's keys, and no
dependency (the search hot path has none). A route taking a form has its multipart body read
there too, strictly (:mod:`app.api.forms`).
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine
from typing import Any
from urllib.parse import parse_qsl

from fastapi import Request, Response, params
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute

from app.api.forms import is_multipart, read_form
from app.errors import InvalidInput


def declared_query_parameters(dependant: Dependant) -> frozenset[str]:
    """The query parameter names a route reads (aliases), its dependencies' included."""
    names: set[str] = set()
    pending = [dependant]
    while pending:
        current = pending.pop()
        names.update(field.alias for field in current.query_params)
        pending.extend(current.dependencies)
    return frozenset(names)


class CheckedQueryRoute(APIRoute):
    """An API route answering 422 to a query parameter it does not declare."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        allowed = declared_query_parameters(self.dependant)
        where = f"{'/'.join(sorted(self.methods or ()))} {self.path}"
        takes = ", ".join(sorted(allowed)) or "none"
        # A route taking a form reads its multipart body strictly (app/api/forms.py) before
        # FastAPI does: FastAPI would answer any error raised in its parse a bare 400.
        takes_form = self.body_field is not None and isinstance(
            self.body_field.field_info, params.Form
        )

        async def checked(request: Request) -> Response:
            query = request.scope.get("query_string", b"")
            if query:
                names = {
                    name for name, _ in parse_qsl(query.decode("latin-1"), keep_blank_values=True)
                }
                unknown = sorted(names - allowed)
                if unknown:
                    plural = "s" if len(unknown) > 1 else ""
                    raise InvalidInput(
                        f"{', '.join(unknown)}: unknown query parameter{plural} of {where} "
                        f"(it takes: {takes})"
                    )
            if takes_form and is_multipart(request):
                await read_form(request)
            return await handler(request)

        return checked
