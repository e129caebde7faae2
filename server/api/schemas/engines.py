"""Wire models of the engines and of a site's engine settings."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from server.api.schemas.common import Strict, StrictIn

PARAMS_DOC = (
    "overrides of the engine's parameters, nested as the engine's defaults are "
    '(GET /v1/engines): e.g. {"particles": {"n": 500}}; checked, 422 naming the '
    "dotted field"
)


class EngineRead(Strict):
    name: str
    uses: list[str] = Field(
        description="event kinds the engine reads (pressure: the barometer rows of imu events); "
        "others are ignored"
    )
    params: dict[str, Any] = Field(description="the engine's default parameters")


class EngineList(Strict):
    items: list[EngineRead]
    count: int


class EngineSettingsIn(StrictIn):
    params: dict[str, Any] = Field(description=PARAMS_DOC)


class EngineSettingsRead(Strict):
    site_id: str
    engine: str
    params: dict[str, Any] = Field(description="what the site overrides")
    effective: dict[str, Any] = Field(
        description="every parameter a new session of the site with this engine starts "
        "with (its own params go over these)"
    )
    problem: str | None = Field(
        None,
        description="why the stored params are not used (a newer server refuses them; "
        "new sessions start from the defaults until they are set again)",
    )


class EngineSettingsList(Strict):
    items: list[EngineSettingsRead]
    count: int
