"""One-shot location from a radio scan."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from server.api.schemas.common import LAX_ARRAY, Id, Strict, StrictIn
from server.api.schemas.events import MAX_READINGS_PER_SCAN, BleReading, WifiReading


class LocateIn(StrictIn):
    site_id: Id
    wifi: Annotated[list[WifiReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []
    ble: Annotated[list[BleReading], Field(max_length=MAX_READINGS_PER_SCAN)] = []


class LocateOut(Strict):
    x_m: float
    y_m: float
    floor: int
    building_id: str
    floor_id: str
    cov_m2: Annotated[tuple[float, float, float, float], LAX_ARRAY] = Field(
        description="position covariance xx, xy, yx, yy in m², calibrated (its 68 % circle "
        "is accuracy_68_m)"
    )
    uncertainty_m: float = Field(description="root of the mean of the two variances (m)")
    accuracy_68_m: float = Field(description="radius (m) that holds 68 % of the errors")
    accuracy_95_m: float = Field(description="radius (m) that holds 95 % of the errors")
    floor_prob: float = Field(description="probability that the floor is right")
    lat: float | None = Field(
        None, description="WGS84 latitude (degrees); null without a geo-referenced building"
    )
    lon: float | None = Field(None, description="WGS84 longitude (degrees); null likewise")
    level: int | None = Field(None, description="the floor's ordinal (0: ground floor)")
    accuracy_m: float | None = Field(None, description="the 68 % radius (m)")
    heading_deg: float | None = Field(None, description="heading from north (degrees)")
    zones: list[str] = Field(
        default_factory=list, description="ids of the zones the position lies in"
    )
