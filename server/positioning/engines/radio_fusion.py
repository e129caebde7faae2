"""The WiFi/BLE side shared by every engine that matches scans.

Per scan (``match``):

1. the scan is matched against the whole map (WKNN, ``papers/002_*`` eq 1-3) if it heard
   at least ``min_matched`` map emitters (one or two beacons tie with hundreds of
   reference points); its floor is chosen by the floor filter (``floor_filter``: the
   filter's prediction times the scan's likelihood of each floor), not by the scan's
   vote alone: on ILC site2 the per-scan vote had an 85 % floor hit rate and every
   engine inherited it;
2. the fix's variance is what the map's training data say a fix of this kind with this
   many matched emitters is worth (``SiteMaps.fix_error``, learned by
   ``mapping.fix_calibration``), times ``fix_var_scale``, at least ``min_fix_var_m2``.

The PDR fusion engines (``two_stage_ekf``, ``everywhere_ekf``) keep ``[x, y, ., heading]``
in an EKF whose first two states are the position, and then (``begin_scan``) decide
whether the filter is lost: ``max_rejects`` whole-map fixes in a row outside the
innovation gate (chi-square on the squared Mahalanobis distance) restart the position at
the whole-map fix; a fix outside the gate is otherwise not used. The position is carried
across a floor change (people change floors on the spot, and floors stack).

Before the map-frame heading is known, a step cannot move the estimate; it only widens
the position variance by the square of its length (``widen``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from server.positioning import floor_filter
from server.positioning.engines.base import SiteMaps
from server.positioning.events import Fix, WifiEvent
from server.positioning.fingerprint import ScanVector, WknnFix, scan_vector, wknn
from server.positioning.kalman import Update, update, wrap_angle
from server.positioning.step_tracker import Scan, Step

FloatArray = NDArray[np.float64]

S = TypeVar("S")

H_POSITION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


EMPTY = np.zeros(0)


@dataclass(frozen=True)
class RadioParams:
    """What every engine that matches scans shares: WKNN, the evidence a fix needs, the
    floor filter (``floor_filter``) and the floor under the fix variance."""

    k: int = 4  # WKNN neighbours K, papers/002_* eq 3
    # scans that match fewer map emitters give no fix: one or two beacons tie with
    # hundreds of reference points all over the building
    min_matched: int = 3
    floor_sd_db: float = 8.0  # RSS error per emitter in the floor likelihood (fingerprint)
    floor_max_emitters: int = 10  # matched emitters counted as independent votes, at most
    floor_change_per_s: float = 0.01  # floor filter: floor changes per second
    # floor under the learned fix variance (fix_error): a fix is never trusted to 2 m
    min_fix_var_m2: float = 4.0
    # the learned variance is that of one fix on its own; a filter that takes fix after
    # fix along a walk meets errors shared by neighbouring scans (the same wrong
    # reference points), so it uses the variance times this factor
    fix_var_scale: float = 1.0

    def check_radio(self) -> None:
        """Raise ValueError naming the first radio parameter out of range."""
        if self.k < 1:
            raise ValueError(f"k must be at least 1, got {self.k}")
        if self.min_matched < 1:
            raise ValueError(f"min_matched must be at least 1, got {self.min_matched}")
        if self.floor_max_emitters < 1:
            raise ValueError(
                f"floor_max_emitters must be at least 1, got {self.floor_max_emitters}"
            )
        if not (math.isfinite(self.floor_change_per_s) and self.floor_change_per_s >= 0):
            raise ValueError(
                f"floor_change_per_s must be non-negative and finite, got {self.floor_change_per_s}"
            )
        check_positive(
            floor_sd_db=self.floor_sd_db,
            min_fix_var_m2=self.min_fix_var_m2,
            fix_var_scale=self.fix_var_scale,
        )


@dataclass(frozen=True)
class Matched:
    """A scan laid over the map, its whole-map WKNN fix (floor chosen with the floor
    filter's prediction) and the fix's variance from its evidence."""

    t_ms: int
    kind: str
    scan: ScanVector
    whole: WknnFix
    var_m2: float

    @property
    def floor_logp(self) -> FloatArray:
        """The floor filter after this scan."""
        return self.whole.floor_logp


def scan_kind(event: Scan) -> str:
    return "wifi" if isinstance(event, WifiEvent) else "ble"


def match(
    maps: SiteMaps,
    event: Scan,
    params: EvidenceParams,
    floor_logp: FloatArray = EMPTY,
    floor_t_ms: int = 0,
) -> Matched | None:
    """Match a scan on the whole map, the floor filtered from ``floor_logp`` (the floor
    filter after its last scan at ``floor_t_ms``; empty: nothing known). None when there
    is no map, the scan matched fewer than ``min_matched`` map columns or no reference
    point shares an emitter with it."""
    if maps.radio is None:
        return None
    kind = scan_kind(event)
    scan = scan_vector(maps.radio, event.readings, kind)
    whole = wknn(
        maps.radio,
        scan,
        k=params.k,
        floor_log_prior=floor_filter.prior(
            floor_logp, floor_t_ms, event.t_ms, params.floor_change_per_s
        ),
        floor_sd_db=params.floor_sd_db,
        floor_max_emitters=params.floor_max_emitters,
        min_matched=params.min_matched,
    )
    if whole is None:
        return None
    learned = maps.fix_error.variance(kind, scan.n_matched)
    var = max(learned * params.fix_var_scale, params.min_fix_var_m2)
    return Matched(event.t_ms, kind, scan, whole, var)


def refined(m: Matched, found: WknnFix | None) -> Matched:
    """The match with another fix of the same scan (a partition's, an aided one's), on
    the floor the whole-map match chose; the whole-map fix when there is none."""
    if found is None:
        return m
    return replace(m, whole=replace(found, floor=m.whole.floor, floor_logp=m.whole.floor_logp))


def position_update(x: FloatArray, P: FloatArray, m: Matched) -> Update:
    return update(x, P, z=[m.whole.x_m, m.whole.y_m], H=H_POSITION, R=m.var_m2 * np.eye(2))


def rejects_after(x: FloatArray, P: FloatArray, m: Matched, rejects: int, gate_chi2: float) -> int:
    """Consecutive whole-map fixes outside the gate, counting this one."""
    check = position_update(x, P, m)
    return rejects + 1 if check.mahalanobis2 > gate_chi2 else 0


def place(x: FloatArray, P: FloatArray, m: Matched) -> tuple[FloatArray, FloatArray]:
    """The state moved onto a fix: position and its variance replaced, its correlation
    with the other states dropped, the other states kept."""
    x = x.copy()
    P = P.copy()
    x[:2] = m.whole.x_m, m.whole.y_m
    P[:2, :] = 0.0
    P[:, :2] = 0.0
    P[0, 0] = P[1, 1] = m.var_m2
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
    floor_logp: FloatArray = EMPTY,
) -> Fix:
    c = P[:2, :2]
    if 0 <= floor < floor_logp.shape[0]:
        diagnostics = {**diagnostics, "floor_prob": float(np.exp(floor_logp[floor]))}
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


def state_fix(state: FilterState, t_ms: int, source: str, diagnostics: dict[str, float]) -> Fix:
    """``to_fix`` of a PDR fusion engine's state."""
    return to_fix(
        state.x,
        state.P,
        state.floor,
        state.heading_known,
        t_ms,
        source,
        diagnostics,
        state.floor_logp,
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
    @property
    def floor_logp(self) -> FloatArray: ...
    @property
    def floor_t_ms(self) -> int: ...
    @property
    def heading_known(self) -> bool: ...


class EvidenceParams(Protocol):
    """The parameters ``match`` reads (``RadioParams`` has them)."""

    @property
    def k(self) -> int: ...
    @property
    def min_matched(self) -> int: ...
    @property
    def floor_sd_db(self) -> float: ...
    @property
    def floor_max_emitters(self) -> int: ...
    @property
    def floor_change_per_s(self) -> float: ...
    @property
    def min_fix_var_m2(self) -> float: ...
    @property
    def fix_var_scale(self) -> float: ...


class ScanParams(EvidenceParams, Protocol):
    """The parameters of a PDR fusion engine that the scan start reads."""

    @property
    def gate_chi2(self) -> float: ...
    @property
    def max_rejects(self) -> int: ...


def begin_scan(
    maps: SiteMaps, event: Scan, state: FilterState, params: ScanParams
) -> ScanStart | None:
    """Match the scan on the whole map and decide floor and restart; None when it
    matches nothing. The new floor is ``matched.whole.floor``, the floor filter after
    the scan ``matched.floor_logp``."""
    m = match(maps, event, params, state.floor_logp, state.floor_t_ms)
    if m is None:
        return None
    diagnostics = {"n_matched": float(m.scan.n_matched), "fix_var_m2": m.var_m2}
    if state.initialized and m.whole.floor != state.floor:
        diagnostics["floor_change"] = 1.0
    if not state.initialized:
        return ScanStart(m, diagnostics, 0, True)
    rejects = rejects_after(state.x, state.P, m, state.rejects, params.gate_chi2)
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
