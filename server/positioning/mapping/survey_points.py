"""A survey point: one scan (and, where measured, the magnetic field) at a known place, as
surveyors give them and placed walks yield them; what the map builder grids."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class SurveyPointData:
    x_m: float
    y_m: float
    floor_level: int
    t_ms: int | None
    wifi: Sequence[tuple[str, float]]
    ble: Sequence[tuple[str, float]]
    mag_ut: tuple[float, float, float] | None
    walk: str | None = None  # the recorded walk the point was taken on
    route: str | None = None  # walks along one route share it
    # each reading's age in ms, parallel to ``wifi`` / ``ble`` (empty or None: fresh)
    wifi_age_ms: Sequence[float | None] = ()
    ble_age_ms: Sequence[float | None] = ()
