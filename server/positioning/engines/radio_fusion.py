"""The WiFi/BLE side shared by the engines that fuse raw-IMU PDR with fingerprint fixes.

Both ``two_stage_ekf`` and ``everywhere_ekf`` keep ``[x, y, ., heading]`` in an EKF whose
first two states are the position, and per scan they:

1. match the scan against the whole map (WKNN, ``papers/002_*`` eq 1-3), which also
   votes the floor. The floor follows each scan's vote; the position is carried across
   a floor change (people change floors on the spot, and a fix on a wrongly voted floor
   is usually still right horizontally, since floors stack). On an inner validation split
   of ILC site2 a decayed vote with hysteresis held the wrong floor longer and lowered the
   floor hit rate at waypoints from 80 % to 70 %;
2. decide whether the filter is lost: ``max_rejects`` whole-map fixes in a row outside
   the innovation gate restart the position at the whole-map fix;
3. update the position with their own engine-specific fix, with the variance of
   ``papers/003_*`` eq 17 floored at ``min_fix_var_m2``.

Before the map-frame heading is known, a step cannot move the estimate; it only widens
the position variance by the square of its length (``widen``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.base import SiteMaps
from server.positioning.events import Fix, WifiEvent
from server.positioning.fingerprint import RadioMap, ScanVector, WknnFix, scan_vector, wknn
from server.positioning.kalman import Update, update, wrap_angle
from server.positioning.step_tracker import Scan, Step

FloatArray = NDArray[np.float64]

S = TypeVar("S")

H_POSITION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class Matched:
    """A scan laid over the map and its whole-map WKNN fix."""

    t_ms: int
    kind: str
    scan: ScanVector
    whole: WknnFix


def match(radio: RadioMap, event: Scan, k: int) -> Matched | None:
    """None when no map column was heard or no reference point shares an emitter."""
    kind = "wifi" if isinstance(event, WifiEvent) else "ble"
    scan = scan_vector(radio, event.readings, kind)
    whole = wknn(radio, scan, k=k)
    return None if whole is None else Matched(event.t_ms, kind, scan, whole)


def fix_variance(found: WknnFix, min_fix_var_m2: float) -> float:
    """``papers/003_*`` eq 17 with a floor (see ``step_ekf`` for why a floor)."""
    return max(found.var_m2, min_fix_var_m2)


def position_update(x: FloatArray, P: FloatArray, found: WknnFix, min_fix_var_m2: float) -> Update:
    var = fix_variance(found, min_fix_var_m2)
    return update(x, P, z=[found.x_m, found.y_m], H=H_POSITION, R=var * np.eye(2))


def rejects_after(
    x: FloatArray,
    P: FloatArray,
    whole: WknnFix,
    rejects: int,
    min_fix_var_m2: float,
    gate_chi2: float,
) -> int:
    """Consecutive whole-map fixes outside the gate, counting this one."""
    check = position_update(x, P, whole, min_fix_var_m2)
    return rejects + 1 if check.mahalanobis2 > gate_chi2 else 0


def place(
    x: FloatArray, P: FloatArray, found: WknnFix, min_fix_var_m2: float
) -> tuple[FloatArray, FloatArray]:
    """The state moved onto a fix: position and its variance replaced, its correlation
    with the other states dropped, the other states kept."""
    x = x.copy()
    P = P.copy()
    x[:2] = found.x_m, found.y_m
    P[:2, :] = 0.0
    P[:, :2] = 0.0
    P[0, 0] = P[1, 1] = fix_variance(found, min_fix_var_m2)
    return x, P


def widen(P: FloatArray, length_m: float) -> FloatArray:
    """A step of unknown direction: the position variance grows by its length squared."""
    P = P.copy()
    P[0, 0] += length_m**2
    P[1, 1] += length_m**2
    return P


def set_heading(
    x: FloatArray, P: FloatArray, heading_rad: float, var_rad2: float
) -> tuple[FloatArray, FloatArray]:
    """Heading (state 3) set to a value with a variance, uncorrelated with the rest."""
    x = x.copy()
    P = P.copy()
    x[3] = heading_rad
    P[3, :] = 0.0
    P[:, 3] = 0.0
    P[3, 3] = var_rad2
    return x, P


def to_fix(
    x: FloatArray,
    P: FloatArray,
    floor: int,
    heading_known: bool,
    t_ms: int,
    source: str,
    diagnostics: dict[str, float],
) -> Fix:
    c = P[:2, :2]
    return Fix(
        t_ms=t_ms,
        x_m=float(x[0]),
        y_m=float(x[1]),
        floor=floor,
        heading_rad=float(x[3]) if heading_known else None,
        cov=(float(c[0, 0]), float(c[0, 1]), float(c[1, 0]), float(c[1, 1])),
        source=source,
        diagnostics=diagnostics,
    )


def check_positive(**values: float) -> None:
    """Raise ValueError naming the first value that is not positive and finite."""
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be positive and finite, got {value}")


def in_building_frame(maps: SiteMaps, floor: int, north_rad: float) -> float:
    """A heading clockwise from north turned into the frame of the floor's building."""
    rotation = maps.floors[floor].rotation_rad if 0 <= floor < len(maps.floors) else 0.0
    return float(wrap_angle(north_rad - rotation))


def turn_between(previous_rad: float, heading_rad: float) -> float:
    """The wrapped change of the phone heading since the previous step (0 when either is
    unknown)."""
    if math.isfinite(heading_rad) and math.isfinite(previous_rad):
        return float(wrap_angle(heading_rad - previous_rad))
    return 0.0


def heading_from_north(
    x: FloatArray,
    P: FloatArray,
    maps: SiteMaps,
    floor: int,
    north_rad: float,
    var_rad2: float,
) -> tuple[FloatArray, FloatArray]:
    """The heading state started from the phone's north-referenced heading."""
    return set_heading(x, P, in_building_frame(maps, floor, north_rad), var_rad2)


def turn_in_place(
    x: FloatArray, P: FloatArray, turn_rad: float, length_m: float
) -> tuple[FloatArray, FloatArray]:
    """A step while the map-frame heading is unknown: the heading state turns with the
    phone, the position stays and its variance grows (``widen``)."""
    x = x.copy()
    x[3] = wrap_angle(x[3] + turn_rad)
    return x, widen(P, length_m)


@dataclass(frozen=True)
class ScanStart:
    """What every scan does first (see the module docstring, steps 1-2)."""

    matched: Matched
    diagnostics: dict[str, float]
    rejects: int  # consecutive whole-map fixes outside the gate, this one included
    restart: bool  # place the filter at the whole-map fix


class FilterState(Protocol):
    """The fields of a PDR fusion engine's state that the scan start reads."""

    @property
    def x(self) -> FloatArray: ...
    @property
    def P(self) -> FloatArray: ...  # noqa: N802 (the covariance, as everywhere)
    @property
    def floor(self) -> int: ...
    @property
    def initialized(self) -> bool: ...
    @property
    def rejects(self) -> int: ...


class ScanParams(Protocol):
    """The parameters of a PDR fusion engine that the scan start reads."""

    @property
    def k(self) -> int: ...
    @property
    def min_fix_var_m2(self) -> float: ...
    @property
    def gate_chi2(self) -> float: ...
    @property
    def max_rejects(self) -> int: ...


def begin_scan(
    radio: RadioMap, event: Scan, state: FilterState, params: ScanParams
) -> ScanStart | None:
    """Match the scan on the whole map and decide floor and restart; None when it
    matches nothing. The new floor is ``matched.whole.floor``."""
    m = match(radio, event, params.k)
    if m is None:
        return None
    diagnostics = {"n_matched": float(m.scan.n_matched)}
    if state.initialized and m.whole.floor != state.floor:
        diagnostics["floor_change"] = 1.0
    if not state.initialized:
        return ScanStart(m, diagnostics, 0, True)
    rejects = rejects_after(
        state.x, state.P, m.whole, state.rejects, params.min_fix_var_m2, params.gate_chi2
    )
    if rejects >= params.max_rejects:
        diagnostics["reinitialised"] = 1.0
        return ScanStart(m, diagnostics, 0, True)
    return ScanStart(m, diagnostics, rejects, False)


def apply_items(
    state: S,
    items: Sequence[Step | Scan],
    on_step: Callable[[S, Step], tuple[S, Fix | None]],
    on_scan: Callable[[S, Scan], tuple[S, Fix | None]],
) -> tuple[S, list[Fix]]:
    """Steps and scans, in the order given, through an engine's handlers."""
    fixes: list[Fix] = []
    for item in items:
        state, fix = on_step(state, item) if isinstance(item, Step) else on_scan(state, item)
        if fix is not None:
            fixes.append(fix)
    return state, fixes
