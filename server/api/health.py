"""Liveness and readiness probes."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from server.api.deps import RuntimeDep
from server.api.gated_route import GatedRoute
from server.services.runtime import check_ready

router = APIRouter(tags=["health"], route_class=GatedRoute)


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    return {"status": "ok"}


class Readiness(BaseModel):
    status: str = Field(description="ok, or unavailable")
    reason: str | None = Field(None, description="which store did not answer")


@router.get(
    "/readyz",
    response_model=Readiness,
    responses={503: {"model": Readiness, "description": "a store does not answer"}},
)
async def readyz(rt: RuntimeDep) -> JSONResponse:
    try:
        await check_ready(rt)
    except Exception as exc:  # any failure of a backing store means "not ready"
        return JSONResponse({"status": "unavailable", "reason": str(exc)[:200]}, status_code=503)
    return JSONResponse({"status": "ok"})
