"""A route that checks the caller's credentials before it reads the request body.

FastAPI reads, parses and validates a body before it runs a route's dependencies: left
alone, anyone could make the server parse a large body (and see its 422) before being
told the key is wrong. Every router of the API uses this route class: for a route with a
body it runs, first, the credential dependencies of the route (those listed in
``server.api.deps.BEFORE_BODY``, innermost first), so a wrong key is answered 401, a key
without the scope 403, another site's thing 404, with the body unread; the framework's
own run of those dependencies then finds their results in ``request.state``.
"""

from __future__ import annotations

from collections.abc import Callable, Coroutine, Iterator
from typing import Any

from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute
from starlette.requests import Request
from starlette.responses import Response

from server.api.deps import BEFORE_BODY, BeforeBody


def _credential_checks(dependant: Dependant) -> Iterator[BeforeBody]:
    for sub in dependant.dependencies:
        yield from _credential_checks(sub)
        if sub.call in BEFORE_BODY:
            yield BEFORE_BODY[sub.call]


class GatedRoute(APIRoute):
    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()
        checks = list(dict.fromkeys(_credential_checks(self.dependant)))
        if self.body_field is None or not checks:
            return handler  # nothing is read before the dependencies run

        async def gated(request: Request) -> Response:
            for check in checks:
                await check(request)
            return await handler(request)

        return gated
