"""Navigation routes: a session guided to a destination, fix by fix."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response, status
from fastapi.exceptions import RequestValidationError

from server.api.deps import BEFORE_BODY, ID, BearerDep, IdPath, RuntimeDep, get_bearer
from server.api.gated_route import GatedRoute
from server.api.routes import route_end
from server.api.schemas.routes import NavigationIn, NavigationOut
from server.positioning.plan.route_following import Settings
from server.services import navigation

router = APIRouter(prefix="/v1/sessions", tags=["navigation"], route_class=GatedRoute)


async def session_driver(request: Request, rt: RuntimeDep, token: BearerDep) -> str:
    """The credential of whoever may guide the session the path names (its token, or an
    admin key of its site), checked before the body is read."""
    if getattr(request.state, "session_driver", None) != token:
        session_id = request.path_params["session_id"]
        if not ID.fullmatch(session_id):
            msg = f"String should match pattern '{ID.pattern}'"
            error = {"loc": ("path", "session_id"), "msg": msg, "type": "string_pattern_mismatch"}
            raise RequestValidationError([error])
        await navigation.authorize_driver(rt, session_id, token)
        request.state.session_driver = token
    return token


async def _session_driver_before_body(request: Request) -> str:
    token: str = await BEFORE_BODY[get_bearer](request)
    return await session_driver(request, request.app.state.runtime, token)


BEFORE_BODY[session_driver] = _session_driver_before_body
SessionDriver = Annotated[str, Depends(session_driver)]


@router.put("/{session_id}/navigation")
async def put_navigation(
    session_id: IdPath, body: NavigationIn, rt: RuntimeDep, token: SessionDriver
) -> NavigationOut:
    """Guide the session from its latest fix to ``destination`` (the session's token, or an
    admin key of its site). From the next batch on, every fix carries ``navigation``:
    what is left, the next instruction, whether the walker is on the route, the fix
    snapped to the route; leaving the route for ``reroute_after_s`` re-routes from the
    fix, reaching the destination ends the navigation. ``rerouted``, ``floor_change`` and
    ``arrived`` events go in the fix, on the live socket and to the site's webhooks."""
    settings = body.settings
    found = await navigation.start(
        rt,
        session_id,
        token,
        route_end(body.destination),
        Settings(
            off_route_m=settings.off_route_m,
            arrival_m=settings.arrival_m,
            reroute_after_s=settings.reroute_after_s,
            accessible=settings.accessible,
        ),
    )
    return NavigationOut.model_validate(found)


@router.get("/{session_id}/navigation")
async def get_navigation(session_id: IdPath, rt: RuntimeDep, token: BearerDep) -> NavigationOut:
    """The session's navigation (its token, or a viewer key of its site): the route being
    followed and where the latest fix stands on it; 404 when it is not navigating."""
    return NavigationOut.model_validate(await navigation.read(rt, session_id, token))


@router.delete("/{session_id}/navigation", status_code=status.HTTP_204_NO_CONTENT)
async def delete_navigation(session_id: IdPath, rt: RuntimeDep, token: SessionDriver) -> Response:
    """Stop guiding the session (the session's token, or an admin key of its site)."""
    await navigation.stop(rt, session_id, token)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
