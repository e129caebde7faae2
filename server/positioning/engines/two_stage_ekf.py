"""``two_stage_ekf``: Cui et al.'s WiFi/MEMS integration from raw phone sensors.

Stage one (``papers/002_*`` section 6.1, eq 9-17) is the attitude-determination EKF
of ``server.positioning.motion.attitude_ekf``: gyro-driven Euler angles corrected by
gravity, whose yaw gives the phone heading. Steps come from the smoothed-magnitude peak detector
(``papers/002_*`` eq 5-7) with Weinberg step lengths (eq 8), see ``server.positioning.motion.pdr``.

Stage two is the position-tracking EKF on ``B = [x, y, S, psi]`` (eq 18): position,
step length and heading in the map frame (clockwise from the map's north, the y axis).
At each step (eq 21, in the form of ``papers/003_*`` eq 15 that moves with the heading
after the step's turn)::

    psi_k = psi_{k-1} + dpsi_k          dpsi_k: change of the attitude yaw since the last step
    x_k   = x_{k-1} + S_{k-1} sin(psi_k)
    y_k   = y_{k-1} + S_{k-1} cos(psi_k)
    S_k   = S_{k-1}

with ``Q_2`` of eq 22, followed by the update of ``S`` with the Weinberg length ``S_acc``
(eq 23-24). Each WiFi/BLE scan gives a WKNN position (eq 1-3) searched in the "moving
partition" (section 4.1): the reference points within ``partition_radius_m`` (2.5 m, the
farthest a person walks in a second) of the current estimate. The search falls back to
the whole map when the partition holds no usable reference point or when the filter is
lost (``max_rejects`` scans in a row whose whole-map fix fails the innovation gate).

The WiFi heading (section 4.2): a least-squares line through the last four WKNN
positions, pointing from the oldest to the newest, measures ``psi`` when no step since the
oldest of them was part of a turn (the gyro turn detection of section 4.2, here the
turn labels of ``server.positioning.motion.turns``) and the four positions span at least
``min_heading_span_m``. Where the phone knows north (its compass or rotation vector),
``psi`` starts from that heading turned into the building frame (magnetic declination is
not corrected: a few degrees in most places); otherwise it waits for the first WiFi
heading, and until then steps only widen the position variance by ``S²`` instead of
moving the estimate. Later WiFi headings update a known heading only with
``wifi_heading_update`` (off by default: they made both development venues worse).

Where the phone sends a rotation vector, its heading replaces the attitude EKF's yaw
(``_cui_tracker``; the attitude EKF is used without one).

Cui's ``R_2 = diag(1000, 1000, 10, 100)`` (eq 25) does not fit metres and radians, so the
measurement variances are our own (each fix's learned variance, ``scan_fixes``); the
initial ``S = 0.6 m`` is the paper's, the position noise ``Q_2`` ten times the paper's
(chosen on both development venues, see ``TwoStageParams``). Fixes outside the
innovation gate are not used; ``max_rejects`` of them in a row restart the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Annotated

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.engines.shared import pdr_kalman, scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, with_found_steps
from server.positioning.filters.kalman import update, wrap_angle
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import Fix
from server.positioning.model.params import NonNegative, Positive
from server.positioning.motion import pdr
from server.positioning.motion.step_tracker import Scan, Step, TrackerParams, initial_tracker

FloatArray = NDArray[np.float64]

_H_STEP = np.array([[0.0, 0.0, 1.0, 0.0]])
_H_HEADING = np.array([[0.0, 0.0, 0.0, 1.0]])


def _cui_tracker() -> TrackerParams:
    """Cui's steps (peaks of the smoothed magnitude, Weinberg lengths) with the phone's
    rotation-vector heading where it sends one: Cui's attitude EKF (``heading="attitude"``)
    drifts with the surge and sway of walking, and on the inner validation splits the
    rotation vector gave IPIN 39.4 m against 42.9 m (IPIN score) and ILC site2 15.1 m
    against 15.1 m (mean), bench/accuracy.md."""
    return TrackerParams(
        heading="rotation", steps=pdr.PdrParams(detector="cui", length_model="weinberg")
    )


@dataclass(frozen=True)
class TwoStageParams(pdr_kalman.StepFusionParams):
    """Parameters of ``two_stage_ekf``; the position noise per step is 0.1 m² rather than
    papers/002_* eq 22's 0.01, and 3 gated fixes in a row restart rather than 6
    (``KalmanParams``, chosen on both development venues)."""

    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.85, 0.20, 1.40, 3.50))

    tracker: TrackerParams = field(default_factory=_cui_tracker)
    partition_radius_m: Positive = 2.5  # papers/002_* section 4.1
    q_step_m2: NonNegative = 0.0001  # papers/002_* eq 22
    initial_step_m: Positive = 0.6  # papers/002_* eq 19
    p0_step_m2: Positive = 0.01  # papers/002_* eq 20
    r_step_m2: Positive = 0.01  # variance of the Weinberg length as a measurement of S
    r_wifi_heading_rad2: Positive = math.radians(20.0) ** 2
    heading_fixes: Annotated[int, Ge(2), Le(100)] = 4  # papers/002_* section 4.2
    # the WiFi heading only starts a heading the phone does not give; updating a known
    # one with it made the inner validation splits worse on both venues (IPIN P75 16.6
    # against 22.7 m without the updates, ILC site2 16.4 against 16.6 m; bench/accuracy.md)
    wifi_heading_update: bool = False
    min_heading_span_m: NonNegative = 3.0

    @property
    def process_noise(self) -> FloatArray:
        return self.noise(self.q_step_m2)


@dataclass(frozen=True, kw_only=True)
class TwoStageState(pdr_kalman.FilterState):
    """``FilterState`` with ``x = [x_m, y_m, step_m, heading_rad]``, and what the WiFi
    heading needs."""

    fixes: FloatArray  # (heading_fixes, 3) [t_ms, x, y] of recent WKNN positions, NaN-padded
    turn_t_ms: float  # time of the last step that was not straight walking


def initial_state(params: TwoStageParams) -> TwoStageState:
    return TwoStageState(
        tracker=initial_tracker(params.tracker),
        x=np.array([0.0, 0.0, params.initial_step_m, 0.0]),
        P=np.diag([params.min_fix_var_m2] * 2 + [params.p0_step_m2, math.pi**2]),
        fixes=np.full((params.heading_fixes, 3), np.nan),
        turn_t_ms=-math.inf,
    )


def _on_step(
    state: TwoStageState,
    step: Step,
    maps: SiteMaps,
    params: TwoStageParams,
    rng: np.random.Generator,
) -> tuple[TwoStageState, Fix | None]:
    del rng  # deterministic
    if not step.straight:
        state = replace(state, turn_t_ms=float(step.t_ms))
    length = float(state.x[2])
    state = pdr_kalman.predict_step(
        state, step, maps, params, length, pdr_kalman.step_motion, params.process_noise
    )
    if not state.initialized:
        return state, None
    u = update(state.x, state.P, z=[step.length_m], H=_H_STEP, R=np.array([[params.r_step_m2]]))
    new = replace(state, x=u.x, P=u.P)
    return new, pdr_kalman.state_fix(new, step.t_ms, "step", {"step_length_m": float(u.x[2])})


def _partition(rp: FloatArray, x: FloatArray, radius_m: float) -> NDArray[np.bool_]:
    """The moving partition: references within ``radius_m`` of the estimate (of any
    floor: only the horizontal position is used)."""
    near: NDArray[np.bool_] = np.hypot(rp[:, 0] - x[0], rp[:, 1] - x[1]) <= radius_m
    return near


def _wifi_heading(fixes: FloatArray, turn_t_ms: float, min_span_m: float) -> float | None:
    """Direction of the least-squares line through the recent WKNN positions, oriented
    from the oldest to the newest (``papers/002_*`` section 4.2); None after a turn, with
    too few positions or when they span less than ``min_span_m``."""
    if np.isnan(fixes).any() or turn_t_ms >= fixes[0, 0]:
        return None
    centred = fixes[:, 1:] - fixes[:, 1:].mean(axis=0)
    direction = np.linalg.svd(centred)[2][0]
    along = centred @ direction
    if float(np.ptp(along)) < min_span_m:
        return None
    if along[-1] < along[0]:
        direction = -direction
    return math.atan2(float(direction[0]), float(direction[1]))


def _select(
    state: TwoStageState, m: scan_fixes.Matched, maps: SiteMaps, params: TwoStageParams
) -> tuple[scan_fixes.Matched, dict[str, float]]:
    """The scan matched in the moving partition (the whole-map fix when it holds no
    usable reference)."""
    near = _partition(scan_fixes.reference_xy(maps), state.x, params.partition_radius_m)
    used = scan_fixes.constrained(maps, m, params, near=near)
    return used, {"partition": 1.0 if used is not m else 0.0}


def _remember(
    state: TwoStageState, taken: pdr_kalman.Taken, params: TwoStageParams
) -> tuple[TwoStageState, dict[str, float]]:
    """The whole-map fix joins the recent WKNN positions; after an update (not at a
    restart) their WiFi heading starts the heading, or updates it with
    ``wifi_heading_update``."""
    m = taken.matched
    fixes = np.roll(state.fixes, -1, axis=0)
    fixes[-1] = m.t_ms, m.whole.x_m, m.whole.y_m
    state = replace(state, fixes=fixes)
    if taken.restart:
        return state, {}
    heading = _wifi_heading(state.fixes, state.turn_t_ms, params.min_heading_span_m)
    if heading is None:
        return state, {}
    if not state.heading_known:
        x, P = pdr_kalman.set_heading(state.x, state.P, heading, params.r_wifi_heading_rad2)
        state = replace(state, x=x, P=P, heading_known=True)
    elif params.wifi_heading_update:
        h = update(
            state.x,
            state.P,
            z=[heading],
            H=_H_HEADING,
            R=np.array([[params.r_wifi_heading_rad2]]),
            residual=lambda z, zp: wrap_angle(z - zp),
        )
        x = h.x
        x[3] = wrap_angle(x[3])
        state = replace(state, x=x, P=h.P)
    return state, {"wifi_heading_rad": heading}


def _on_scan(
    state: TwoStageState,
    event: Scan,
    maps: SiteMaps,
    params: TwoStageParams,
    rng: np.random.Generator,
) -> tuple[TwoStageState, Fix | None]:
    del rng  # deterministic
    return pdr_kalman.scan_update(state, event, maps, params, _select, _remember)


SPEC = EngineSpec(
    name="two_stage_ekf",
    params_type=TwoStageParams,
    state_type=TwoStageState,
    initial_state=initial_state,
    uses=pdr_kalman.USES,
    handlers=pdr_kalman.routes(_on_step, _on_scan),
    prepass=with_found_steps,
)
