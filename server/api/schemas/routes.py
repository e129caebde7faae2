"""Routes and navigation: where a route starts and ends, and a route as the wire
carries it."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import ConfigDict, Field, model_validator

from server.api.schemas.common import Coordinate, FiniteFloat, Id, Name, Strict, StrictIn

Latitude = Annotated[float, Field(ge=-90, le=90, allow_inf_nan=False)]
Longitude = Annotated[float, Field(ge=-180, le=180, allow_inf_nan=False)]
ZoneId = Annotated[str, Field(pattern=r"^[A-Za-z0-9._:~-]{1,64}$")]


class RouteEndIn(StrictIn):
    """One end of a route: exactly one of a point of a floor (``floor_id``, ``x_m``,
    ``y_m``: floor metres), a point on the Earth (``lat``, ``lon``, ``level``, and
    ``building_id`` in a site of several geo-referenced buildings), a session's latest fix
    (``session_id``; origins only), a zone (``zone_id``, and ``floor_id`` when the id is on
    several floors: the route ends at its declared entrance or its nearest reachable
    border point) or a named place of the plan (``place``: the id or name of an IMDF unit,
    amenity or anchor, or of a ``"poi"`` feature)."""

    floor_id: Id | None = None
    x_m: Coordinate | None = None
    y_m: Coordinate | None = None
    lat: Latitude | None = None
    lon: Longitude | None = None
    level: int | None = Field(None, ge=-1000, le=1000)
    building_id: Id | None = None
    session_id: Id | None = None
    zone_id: ZoneId | None = None
    place: Name | None = None

    @model_validator(mode="after")
    def _one_form(self) -> RouteEndIn:
        forms = [
            self.x_m is not None or self.y_m is not None,
            self.lat is not None or self.lon is not None,
            self.session_id is not None,
            self.zone_id is not None,
            self.place is not None,
        ]
        if sum(forms) != 1:
            raise ValueError(
                "give exactly one of: floor_id with x_m and y_m; lat, lon and level; "
                "session_id; zone_id; place"
            )
        if forms[0] and (self.floor_id is None or self.x_m is None or self.y_m is None):
            raise ValueError("a point of a floor needs floor_id, x_m and y_m")
        if forms[1] and (self.lat is None or self.lon is None or self.level is None):
            raise ValueError("a point on the Earth needs lat, lon and level")
        return self


class RouteIn(StrictIn):
    origin: RouteEndIn
    destination: RouteEndIn
    accessible: bool = Field(False, description="lifts, ramps and level ways only")

    @model_validator(mode="after")
    def _session_origin_only(self) -> RouteIn:
        if self.destination.session_id is not None:
            raise ValueError("destination: a session is an origin only")
        return self


class PlaceOut(Strict):
    floor_id: str
    building_id: str
    level: int
    x_m: float
    y_m: float
    lat: float | None = Field(description="WGS84, where the building is geo-referenced")
    lon: float | None


class DestinationOut(PlaceOut):
    name: str | None = Field(description="the zone's or place's name")


class LineString(Strict):
    type: Literal["LineString"]
    coordinates: list[list[float]]


class LegOut(Strict):
    floor_id: str
    building_id: str
    level: int
    length_m: float
    geometry: LineString = Field(description="floor metres")
    geometry_wgs84: LineString | None = Field(
        description="[lon, lat] (RFC 7946), where the building is geo-referenced"
    )


class FloorChangeOut(Strict):
    kind: Literal["stairs", "elevator", "escalator", "ramp", "traversal"]
    name: str | None
    from_floor_id: str
    to_floor_id: str
    from_level: int
    to_level: int
    duration_s: float


class StepOut(PlaceOut):
    kind: str = Field(
        description="start, straight, slight_left/right, left/right, sharp_left/right, "
        "uturn, stairs_up/down, lift_up/down, escalator_up/down, ramp_up/down, "
        "traversal_up/down, arrive"
    )
    text: str = Field(description="the instruction in plain English")
    distance_m: float = Field(description="walked from the previous step to this one")
    along_m: float = Field(description="walked from the route's start to this step")
    bearing_deg: float | None = Field(
        description="the direction walked after this step, degrees clockwise from north"
    )
    to_level: int | None = Field(description="a floor change: the level it ends on")


class RouteOut(Strict):
    length_m: float
    duration_s: float = Field(description="walking at 1.2 m/s plus each floor change's time")
    accessible: bool
    origin: PlaceOut
    destination: DestinationOut
    legs: list[LegOut] = Field(description="one per floor walked, in order")
    floor_changes: list[FloorChangeOut]
    steps: list[StepOut]


class NavigationSettingsIn(StrictIn):
    off_route_m: FiniteFloat = Field(
        5.0, gt=0, le=100, description="a fix farther than this from the route is off it (m)"
    )
    arrival_m: FiniteFloat = Field(
        3.0, gt=0, le=50, description="within this of the destination the walker has arrived (m)"
    )
    reroute_after_s: FiniteFloat = Field(
        4.0,
        ge=0,
        le=120,
        description="off the route this long, and for three fixes or more, re-routes (s)",
    )
    accessible: bool = Field(False, description="lifts, ramps and level ways only")


class NavigationIn(StrictIn):
    destination: RouteEndIn
    settings: NavigationSettingsIn = NavigationSettingsIn()

    @model_validator(mode="after")
    def _no_session(self) -> NavigationIn:
        if self.destination.session_id is not None:
            raise ValueError("destination: a session is an origin only")
        return self


class NavigationEventOut(Strict):
    model_config = ConfigDict(extra="allow")
    type: Literal["rerouted", "floor_change", "arrived"]
    t: int
    route_version: int


class NavigationProgressOut(Strict):
    """What each fix of a navigating session carries in ``navigation``."""

    status: Literal["navigating", "arrived"]
    destination: DestinationOut
    remaining_m: float = Field(description="metres left along the route")
    remaining_s: float = Field(description="seconds left: walking, and the floor changes left")
    on_route: bool
    off_route_m: float | None = Field(description="the fix's distance to the route (m)")
    step_index: int = Field(
        description="the last step passed (the current one): its index in the route's steps"
    )
    next_step: StepOut | None
    distance_to_next_m: float | None
    instruction: str = Field(
        description='"In 12 m, turn left"; "Continue" while the fix\'s 68 % radius is larger '
        "than the distance to the step it would announce"
    )
    withheld: bool = Field(description="the next step is not announced yet (see instruction)")
    snapped: PlaceOut = Field(description="the fix on the route, for display")
    route_version: int = Field(description="how many times the session was re-routed")
    events: list[NavigationEventOut]


class NavigationOut(Strict):
    route: RouteOut
    navigation: NavigationProgressOut | None = Field(
        description="where the session's latest fix stands on the route"
    )
