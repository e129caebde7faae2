"""What the Kalman filter engines share: a state ``[x, y, ., heading]`` whose first two
entries are the position, the per-step motion, the scan start, and the fix.

The PDR fusion engines (``two_stage_ekf``, ``everywhere_ekf``) find their own steps in
the phone's raw samples (``step_tracker``; their pre-pass, ``spec``) and keep
``[x, y, ., heading]`` in an EKF (``FilterState``, ``StepFusionParams``);
at each WiFi/BLE scan they first (``begin_scan``) match it on the whole map
(``scan_fixes.match``) and decide whether the filter is lost: ``max_rejects``
whole-map fixes in a row outside the innovation gate (chi-square on the squared
Mahalanobis distance) restart the position at the whole-map fix; a fix outside the gate
is otherwise not used. The position is carried across a floor change (people change
floors on the spot, and floors stack). ``scan_update`` is the whole scan, with the
engine's own choice of the fix the filter takes (the whole-map one, or one matched again
near its estimate) and of what it remembers of the scan.

Before the map-frame heading is known, a step cannot move the estimate; it only widens
the position variance by the square of its length (``widen``).

The motion of a step of length ``S`` after a turn (``papers/002_*`` eq 21 in the form of
``papers/003_*`` eq 15, with the heading after the turn) and its Jacobian
(``papers/003_*`` eq 16) are ``step_motion``; ``step_ekf`` and ``two_stage_ekf`` share it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared.scan_fixes import (
    EMPTY,
    Matched,
    RadioParams,
    in_building_frame,
    match,
    on_floor_change,
    position_update,
    to_fix,
    turn_between,
)
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import Handler, Route, on, on_scans
from server.positioning.filters.kalman import predict_ekf, wrap_angle
from server.positioning.model.events import BleEvent, Fix, WifiEvent
from server.positioning.model.params import AtLeastOne, NonNegative, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion.barometer import BaroState, FloorChange, initial_barometer
from server.positioning.motion.step_tracker import Scan, Step, TrackerParams, TrackerState

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class KalmanParams(RadioParams):
    """What the Kalman filter engines share: position and heading noise per step and
    the innovation gate."""

    # process noise on x and y per step: 0.1 m² rather than papers/002_* eq 22's 0.01,
    # chosen on the inner validation splits of both ILC site2 and the IPIN logs
    # (bench/accuracy.md, "Choices")
    q_x_m2: NonNegative = 0.1
    q_y_m2: NonNegative = 0.1
    q_heading_rad2: NonNegative = 0.01  # process noise on the heading per step, papers/002_* eq 22
    gate_chi2: Positive = 13.82  # innovation gate on WiFi/BLE positions: chi2(2 dof), 99.9 %
    # consecutive gated fixes before re-initialising at the fix: 3 rather than 6, chosen
    # on both development venues (bench/accuracy.md, "Choices")
    max_rejects: AtLeastOne = 3

    def noise(self, q_third: float) -> FloatArray:
        """Process noise covariance per step, shape (4, 4) (``papers/002_*`` eq 22), with
        ``q_third`` on the engine's third state."""
        return np.diag([self.q_x_m2, self.q_y_m2, q_third, self.q_heading_rad2])


@dataclass(frozen=True, kw_only=True)
class FilterState:
    """The fields every PDR fusion engine's state has."""

    tracker: TrackerState
    x: FloatArray = field(metadata=shape(4))  # [x_m, y_m, ., heading_rad]
    P: FloatArray = field(metadata=shape(4, 4))
    floor: int = -1  # floor index of the estimate; -1 while uninitialised
    initialized: bool = False  # False until the first fix
    heading_known: bool = False  # the map-frame heading is known
    last_phone_heading: float = math.nan  # heading of the previous step (NaN before any)
    rejects: int = 0  # whole-map fixes in a row outside the gate
    # the floor filter after its last scan (empty: none yet)
    floor_logp: FloatArray = field(default_factory=lambda: EMPTY)
    floor_t_ms: int = 0  # time of that scan
    baro: BaroState = field(default_factory=initial_barometer)  # floor changes by pressure


@dataclass(frozen=True)
class StepFusionParams(KalmanParams):
    """``KalmanParams`` of an engine that finds its own steps in raw samples."""

    tracker: TrackerParams = field(default_factory=TrackerParams)
    p0_north_heading_rad2: Positive = math.radians(20.0) ** 2  # heading from the phone's compass


F = TypeVar("F", bound=FilterState)
Q = TypeVar("Q", bound=StepFusionParams)

# what a PDR engine reads: raw IMU blocks (it finds its own steps; the phone's step events
# are ignored), WiFi/BLE scans and the barometer
USES = frozenset({"imu", "wifi", "ble", "pressure"})


def routes(
    on_step: Handler[F, Step, Q], on_scan: Handler[F, WifiEvent | BleEvent, Q]
) -> tuple[Route[F, Q], ...]:
    """A PDR engine's batch: the steps its pre-pass (``spec.with_found_steps``) finds in
    the raw samples, its scans and the barometer's floor changes, through the filter in
    time order; deterministic."""
    return (on(Step, on_step), on(FloorChange, on_floor_change), *on_scans(on_scan))


def turn_of(state: F, step: Step) -> tuple[F, float]:
    """The phone's turn since the previous step (0 when either heading is unknown), and
    the state remembering this step's heading."""
    turn = turn_between(state.last_phone_heading, step.heading_rad)
    if math.isfinite(step.heading_rad):
        state = replace(state, last_phone_heading=step.heading_rad)
    return state, turn


def predict_step(
    state: F,
    step: Step,
    maps: SiteMaps,
    params: StepFusionParams,
    length_m: float,
    motion: Callable[[FloatArray, float], tuple[FloatArray, FloatArray]],
    noise: FloatArray,
) -> F:
    """The filter moved by one step of ``length_m`` after the phone's turn since the
    previous step (``turn_of``; an uninitialised filter only remembers the step's
    heading): where the map-frame heading is unknown it starts from the phone's north if
    the step has one, else the step only turns the heading and widens the position
    (``turn_in_place``); with a heading, the EKF prediction with the engine's ``motion``
    model and process ``noise``."""
    state, turn_rad = turn_of(state, step)
    if not state.initialized:
        return state
    x, P = state.x, state.P
    if not state.heading_known and math.isfinite(step.north_rad):
        # the phone knows north: start the heading from it, in the building's frame
        x, P = heading_from_north(
            x, P, maps, state.floor, step.north_rad, params.p0_north_heading_rad2
        )
        state = replace(state, heading_known=True)
        turn_rad = 0.0
    if not state.heading_known:
        x, P = turn_in_place(x, P, turn_rad, length_m)
    else:
        x_pred, jacobian = motion(x, turn_rad)
        x, P = predict_ekf(x_pred, P, jacobian, noise)
    return replace(state, x=x, P=P)


def step_motion(x: FloatArray, turn_rad: float) -> tuple[FloatArray, FloatArray]:
    """One step of length ``x[2]`` after a turn of ``turn_rad``: the predicted state and
    the Jacobian of the motion model (module docstring)."""
    length, psi = x[2], x[3] + turn_rad
    s, c = math.sin(psi), math.cos(psi)
    F = np.array(
        [
            [1.0, 0.0, s, length * c],
            [0.0, 1.0, c, -length * s],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    x_pred = np.array([x[0] + length * s, x[1] + length * c, length, wrap_angle(psi)])
    return x_pred, F


def state_fix(state: FilterState, t_ms: int, source: str, diagnostics: dict[str, float]) -> Fix:
    """``scan_fixes.to_fix`` of a PDR fusion engine's state."""
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
class ScanStart(Generic[F]):
    """What every scan does first (see the module docstring)."""

    state: F  # on the scan's floor; placed at the whole-map fix when ``restart``
    matched: Matched
    diagnostics: dict[str, float]
    rejects: int  # consecutive whole-map fixes outside the gate, this one included
    restart: bool  # the filter was placed at the whole-map fix


def begin_scan(maps: SiteMaps, event: Scan, state: F, params: KalmanParams) -> ScanStart[F] | None:
    """Match the scan on the whole map, move the filter to the floor it chose (with the
    floor filter after it) and decide whether to restart there; None when it matches
    nothing."""
    m = match(maps, event, params, state.floor_logp, state.floor_t_ms, state.baro)
    if m is None:
        return None
    diagnostics = {"n_matched": float(m.n_matched), "fix_var_m2": m.var_m2}
    if state.initialized and m.whole.floor != state.floor:
        diagnostics["floor_change"] = 1.0
    restart, rejects = True, 0
    if state.initialized:
        rejects = rejects_after(state.x, state.P, m, state.rejects, params.gate_chi2)
        restart = rejects >= params.max_rejects
        if restart:
            diagnostics["reinitialised"] = 1.0
            rejects = 0
    state = replace(state, floor=m.whole.floor, floor_logp=m.floor_logp, floor_t_ms=m.t_ms)
    if restart:
        x, P = place(state.x, state.P, m)
        state = replace(state, x=x, P=P, initialized=True, rejects=0)
    return ScanStart(state, m, diagnostics, rejects, restart)


def update_position(
    state: F, used: Matched, rejects: int, gate_chi2: float, diagnostics: dict[str, float]
) -> tuple[F, bool]:
    """The position updated by a fix of the scan unless it falls outside the innovation
    gate (then it is not used: ``begin_scan`` counted it in ``rejects``); whether it was
    used."""
    u = position_update(state.x, state.P, used)
    diagnostics["mahalanobis2"] = u.mahalanobis2
    if u.mahalanobis2 > gate_chi2:
        return replace(state, rejects=rejects), False
    return replace(state, x=u.x, P=u.P, rejects=rejects), True


@dataclass(frozen=True)
class Taken:
    """What the filter did with a scan's fix (``scan_update``)."""

    matched: Matched  # the scan's whole-map match
    used: Matched  # the fix the filter took: ``matched`` at a restart
    restart: bool  # the filter was placed at ``matched``


# the fix the filter is to take of the scan's match (on the state at the scan): the
# whole-map one, or one matched again among the references the engine keeps; and what to
# note of the choice in the scan's diagnostics
Select = Callable[[F, Matched, SiteMaps, Q], tuple[Matched, dict[str, float]]]
# the state remembering what the filter did with the scan's fix; and what to note of it in
# the scan's diagnostics
Remember = Callable[[F, Taken, Q], tuple[F, dict[str, float]]]


def scan_update(
    state: F,
    event: Scan,
    maps: SiteMaps,
    params: Q,
    select: Select[F, Q],
    remember: Remember[F, Q],
) -> tuple[F, Fix | None]:
    """A PDR engine's scan: ``begin_scan``, then, unless that restarted the filter at the
    whole-map fix, the position updated by the fix the engine selects
    (``update_position``); the engine remembers either. A fix when the filter restarted
    or took the scan's fix."""
    start = begin_scan(maps, event, state, params)
    if start is None or maps.radio is None:
        return state, None
    m, diagnostics, state = start.matched, start.diagnostics, start.state
    if start.restart:
        taken = Taken(m, m, restart=True)
    else:
        used, noted = select(state, m, maps, params)
        diagnostics.update(noted)
        state, accepted = update_position(state, used, start.rejects, params.gate_chi2, diagnostics)
        if not accepted:
            return state, None
        taken = Taken(m, used, restart=False)
    new, noted = remember(state, taken, params)
    return new, state_fix(new, m.t_ms, m.kind, {**diagnostics, **noted})
