"""Route routes: the way between two places of a site, leg by leg and turn by turn."""

from __future__ import annotations

from fastapi import APIRouter

from server.api.deps import IdPath, RuntimeDep, ViewerDep
from server.api.gated_route import GatedRoute
from server.api.schemas.routes import RouteEndIn, RouteIn, RouteOut
from server.services import routes
from server.services.routes import RouteEnd

router = APIRouter(prefix="/v1", tags=["routes"], route_class=GatedRoute)


def route_end(end: RouteEndIn) -> RouteEnd:
    return RouteEnd(**end.model_dump())


@router.post("/sites/{site_id}/routes", dependencies=[ViewerDep])
async def post_route(site_id: IdPath, body: RouteIn, rt: RuntimeDep) -> RouteOut:
    """The quickest route from ``origin`` to ``destination`` (walking time, floor changes
    by their kind: a lift's wait, stairs slower than a corridor; ``accessible``: lifts and
    ramps only): its legs per floor (floor metres, and WGS84 where geo-referenced), its
    floor changes and turn-by-turn steps. 404 naming the end at fault when there is none
    (outside walkable space, a floor nothing joins)."""
    found = await routes.plan_route(
        rt, site_id, route_end(body.origin), route_end(body.destination), body.accessible
    )
    return RouteOut.model_validate(found)
