"""Dependencies shared by the routers: the runtime, a SQL transaction, credentials."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Path, Request, WebSocket
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.ext.asyncio import AsyncSession

from server.services import auth
from server.services.errors import Unauthorized
from server.services.runtime import Runtime

_bearer = HTTPBearer(auto_error=False, description="admin API key or session token")


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
IdPath = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$")]


async def get_sql(rt: RuntimeDep) -> AsyncIterator[AsyncSession]:
    async with rt.transaction() as session:
        yield session


# scope="function": the transaction commits before the response leaves, so nothing is
# acknowledged that could still fail to commit
SqlDep = Annotated[AsyncSession, Depends(get_sql, scope="function")]


async def get_bearer(
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> str:
    if credentials is None or not credentials.credentials:
        raise Unauthorized("missing bearer token", field="authorization")
    return credentials.credentials


BearerDep = Annotated[str, Depends(get_bearer)]


async def require_admin(rt: RuntimeDep, token: BearerDep) -> None:
    async with rt.transaction() as s:
        if not await auth.is_admin_key(s, rt.settings, token):
            raise Unauthorized("not a valid admin API key", field="authorization")


AdminDep = Depends(require_admin)
