"""Dependencies shared by the routers: the runtime, a SQL transaction, credentials."""

from __future__ import annotations

import re
from collections.abc import AsyncIterator, Awaitable, Callable
from dataclasses import dataclass
from typing import Annotated, Any

from fastapi import Depends, Path, Query, Request, WebSocket
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.ext.asyncio import AsyncSession
from starlette.requests import HTTPConnection

from server.api.schemas.common import ID_PATTERN
from server.api.schemas.pages import DEFAULT_LIMIT, MAX_CURSOR_CHARS, MAX_LIMIT, decode_cursor
from server.services import auth, limits, sites
from server.services.errors import Forbidden, Invalid, Unauthorized, not_found
from server.services.runtime import Runtime

_bearer = HTTPBearer(auto_error=False, description="an API key or a session token")


# Every dependency is ``async def``: FastAPI runs a plain ``def`` one in a worker thread,
# a thread hop per request for what is a field lookup.


async def get_runtime(request: Request) -> Runtime:
    runtime: Runtime = request.app.state.runtime
    return runtime


async def get_ws_runtime(websocket: WebSocket) -> Runtime:
    runtime: Runtime = websocket.app.state.runtime
    return runtime


RuntimeDep = Annotated[Runtime, Depends(get_runtime)]
# ids in paths are the 32-hex-character ids this service hands out
ID = re.compile(ID_PATTERN)
IdPath = Annotated[str, Path(pattern=ID_PATTERN)]


async def get_sql(rt: RuntimeDep) -> AsyncIterator[AsyncSession]:
    async with rt.transaction() as session:
        yield session


# scope="function": the transaction commits before the response leaves, so nothing is
# acknowledged that could still fail to commit
SqlDep = Annotated[AsyncSession, Depends(get_sql, scope="function")]


# Credentials before the body: FastAPI reads and validates a route's body before it runs
# the route's dependencies, so a route with a body runs the credential dependencies below
# first (``server.api.gated_route``): each says, in BEFORE_BODY, how it checks itself from
# the request alone, and keeps what it found in ``request.state`` so that the run the
# framework makes later costs nothing.
BeforeBody = Callable[[Request], Awaitable[Any]]
BEFORE_BODY: dict[Callable[..., Any], BeforeBody] = {}


async def get_bearer(
    request: Request,
    rt: RuntimeDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    """The bearer token, once the address is not barred for failing too often (what
    fails is counted by ``server.api.errors``)."""
    known: str | None = getattr(request.state, "bearer", None)
    if known is not None:
        return known
    await limits.refuse_failing_address(rt, client_address(request))
    if credentials is None or not credentials.credentials:
        raise Unauthorized("missing bearer token", field="authorization")
    request.state.bearer = credentials.credentials
    return credentials.credentials


async def _bearer_before_body(request: Request) -> str:
    return await get_bearer(request, request.app.state.runtime, await _bearer(request))


BEFORE_BODY[get_bearer] = _bearer_before_body
BearerDep = Annotated[str, Depends(get_bearer)]


def client_address(connection: HTTPConnection) -> str:
    """The client's address (uvicorn puts the ``X-Forwarded-For`` of a proxy listed in
    ``Settings.trusted_proxies`` here, and only of those)."""
    return connection.client.host if connection.client else "unknown"


async def get_address(request: Request) -> str:
    return client_address(request)


AddressDep = Annotated[str, Depends(get_address)]


async def get_principal(request: Request, rt: RuntimeDep, token: BearerDep) -> auth.Principal:
    known: auth.Principal | None = getattr(request.state, "principal", None)
    if known is not None:
        return known
    async with rt.read() as s:
        principal = await auth.authenticate(s, rt.settings, token)
    if principal is None:
        raise Unauthorized("not a valid API key", field="authorization")
    request.state.principal = principal
    return principal


PrincipalDep = Annotated[auth.Principal, Depends(get_principal)]

# what a route's path names a thing of a site by, and how it is called in a 404
_PATH_THINGS = (("floor_id", "floor"), ("building_id", "building"), ("site_id", "site"))


async def _check_site(rt: Runtime, principal: auth.Principal, params: dict[str, str]) -> None:
    """For a key of one site, refuse a site, building or floor the path names that is not
    of its site exactly as one that does not exist: 404, whatever else the request holds
    (a key for every site is left to the route, which answers 404 for what is missing)."""
    named = [(param, kind) for param, kind in _PATH_THINGS if param in params]
    if principal.site_id is None or not named:
        return
    param, kind = named[0]
    thing_id = params[param]
    if kind == "site":
        site_id: str | None = thing_id
    else:
        async with rt.read() as s:
            site_id = await sites.site_of(s, params.get("building_id"), params.get("floor_id"))
    if site_id is None or not principal.sees(site_id):
        raise not_found(kind, thing_id)


def scoped(scope: str) -> Any:
    """A dependency that lets a request through only with a key holding ``scope`` (401
    without a valid key, 403 without the scope, 404 for another site's resources)."""

    async def check(request: Request, rt: RuntimeDep, principal: PrincipalDep) -> auth.Principal:
        if getattr(request.state, "admitted", None) == scope:
            return principal
        principal.require(scope)
        await _check_site(rt, principal, dict(request.path_params))
        request.state.admitted = scope  # server.api.body_limit: the bulk limit applies
        return principal

    async def before_body(request: Request) -> auth.Principal:
        rt: Runtime = request.app.state.runtime
        token = await _bearer_before_body(request)
        return await check(request, rt, await get_principal(request, rt, token))

    BEFORE_BODY[check] = before_body
    return Depends(check)


AdminDep = scoped("admin")
MapsWriteDep = scoped("maps:write")
ViewerDep = scoped("viewer")
# the principal itself, for routes that check a site given in the body or the query
Admin = Annotated[auth.Principal, AdminDep]
MapsWriter = Annotated[auth.Principal, MapsWriteDep]
Viewer = Annotated[auth.Principal, ViewerDep]
Device = Annotated[auth.Principal, scoped("device")]


async def require_global_admin(principal: Admin) -> auth.Principal:
    """An admin key for every site: what keys and new sites need (a site's admin key
    making keys could make itself one for every site)."""
    if principal.site_id is not None:
        raise Forbidden("this needs an admin key for every site", field="authorization")
    return principal


async def _global_admin_before_body(request: Request) -> auth.Principal:
    return await require_global_admin(await BEFORE_BODY[AdminDep.dependency](request))


BEFORE_BODY[require_global_admin] = _global_admin_before_body
GlobalAdminDep = Depends(require_global_admin)


@dataclass(frozen=True)
class PageQuery:
    """A page a list route was asked for: its size and the key it starts after."""

    limit: int
    after: tuple[Any, ...] | None


def page_query(name: str, key: tuple[type, ...]) -> Any:
    """The ``limit`` and ``cursor`` query parameters of list ``name`` (sorted by a key of
    ``key`` types; ``schemas.pages``), checked: 422 naming the field."""

    async def page(
        limit: Annotated[
            int, Query(ge=1, le=MAX_LIMIT, description=f"items per page, at most {MAX_LIMIT}")
        ] = DEFAULT_LIMIT,
        cursor: Annotated[
            str | None,
            Query(
                min_length=1,
                max_length=MAX_CURSOR_CHARS,
                description="the next_cursor of the page before; none for the first page",
            ),
        ] = None,
    ) -> PageQuery:
        if cursor is None:
            return PageQuery(limit, None)
        try:
            return PageQuery(limit, decode_cursor(name, key, cursor))
        except ValueError as exc:
            raise Invalid(str(exc), field="cursor") from None

    return Depends(page)
