"""``everywhere_ekf``: the online positioning of Mansour et al.'s *Everywhere* framework.

PDR (``papers/003_*`` section III, ``server.positioning.motion.pdr``): peak/valley step detection
on the vertical acceleration, step lengths from eq 1, the heading from gyro integration
fused with the compass during quasi-static magnetic field periods, and the turn /
straight-walk labels from ``Δh_max`` with ``λ_l``, ``λ_h``.

Fingerprinting with PDR-aided selection of the K nearest reference points (section V.A,
eq 11-14). When every step since the previous scan was straight walking and the last two
fingerprint positions are known, each reference point ``i`` is charged, on top of its
signal distance, with

* ``ξ_Δd = | |RP_i - FP_{t-1}| - Σ sl_k |`` (eq 13): how far the distance from the last
  fingerprint position to it is from the distance walked since, and
* ``ξ_ΔH = |bearing(FP_{t-1} -> RP_i) - bearing(FP_{t-2} -> FP_{t-1})|`` (eq 14): how much
  the direction to it turns away from the direction of walking,

summed as in the paper (metres and radians added to decibels; ``aid_distance_db_per_m``
and ``aid_heading_db_per_rad`` are 1). During turns, when static, or without two earlier
positions the selection is plain signal matching.

The EKF (section V.B, eq 15-17) keeps ``[x, y, s, h]``: position, step-length correction
``s`` (a step moves ``(1 + s) d``) and heading in the map frame. At each step (eq 15, with
the heading after the step's turn)::

    h_t = h_{t-1} + Δh_t
    x_t = x_{t-1} + (1 + s) d_t sin(h_t)
    y_t = y_{t-1} + (1 + s) d_t cos(h_t)
    s_t = s_{t-1}

with the transition matrix of eq 16. Writing the filter on the full state rather than on
the error state ``[δE, δN, δs, δh]`` gives the same estimates (the error-state form is its
linearisation about the PDR solution) and lets the engine share the EKF steps of
``server.positioning.filters.kalman``. A fingerprint position updates ``x, y`` with the variance
its evidence is worth on the map (``scan_fixes.match``; eq 17's spread is not a
variance), unless it falls outside the innovation gate.

The heading starts from the phone's north-referenced heading (its rotation vector, or the
fused compass without one) turned into the building frame (magnetic declination is not
corrected; the anchor calibration removes it where there are anchors); ``Δh_t`` is the
change of that heading between steps.

Calibration at anchors (eq 18-22): a floor plan may mark anchors, places with a BLE
beacon (elevators, entrances) at known positions (``SiteMaps.anchors``). An anchor is
passed when its beacon is heard at or above its threshold; the position is then updated
at the anchor. When the walk from the previous anchor was straight, the step length is
calibrated (eq 18-19: the anchor distance over the number of steps, as a measurement of
``s`` with ``r_3 = 0.005``) and so is the heading (eq 20-21: the angle between the
measured and the true direction from the previous anchor, ``r_4 = 0.001``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared import pdr_kalman, scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, with_found_steps
from server.positioning.filters.kalman import update, wrap_angle
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Fix, radio_key
from server.positioning.model.params import AtLeastOne, NonNegative, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion.step_tracker import Scan, Step, TrackerParams, initial_tracker
from server.positioning.plan.anchors import Anchor

FloatArray = NDArray[np.float64]

_H_SCALE = np.array([[0.0, 0.0, 1.0, 0.0]])
_H_HEADING = np.array([[0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class EverywhereParams(pdr_kalman.StepFusionParams):
    """Parameters of ``everywhere_ekf``; the position noise per step (0.1 m² rather than
    papers/002_* eq 22's 0.01) and the restart after 3 gated fixes in a row rather than 6
    are ``KalmanParams``'s, chosen on both development venues."""

    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.80, 0.20, 2.80, 0.20))

    # the phone's rotation-vector heading where it sends one, else Mansour's gyro +
    # compass fusion: on the inner validation splits IPIN P75 15.9 m against 23.0 m,
    # ILC site2 mean 14.5 m against 14.6 m (bench/accuracy.md)
    tracker: TrackerParams = field(default_factory=lambda: TrackerParams(heading="rotation"))
    aid_distance_db_per_m: NonNegative = 1.0  # weight of ξ_Δd (eq 13) against the signal distance
    aid_heading_db_per_rad: NonNegative = 1.0  # weight of ξ_ΔH (eq 14)
    q_scale: NonNegative = 0.0001
    p0_scale: Positive = 0.01
    r_step_scale: Positive = 0.005  # eq 19
    r_anchor_heading_rad2: Positive = 0.001  # eq 21
    anchor_var_m2: Positive = 1.0
    anchor_min_steps: AtLeastOne = 5  # shorter walks between anchors calibrate nothing

    @property
    def process_noise(self) -> FloatArray:
        return self.noise(self.q_scale)


@dataclass(frozen=True, kw_only=True)
class EverywhereState(pdr_kalman.FilterState):
    """``FilterState`` with ``x = [x_m, y_m, scale_correction, heading_rad]``, and what
    the aided selection and the anchor calibration need."""

    # fingerprint positions at t-2 and t-1, NaN when unknown
    fp: FloatArray = field(metadata=shape(2, 2))
    walked_m: float  # PDR distance since the last scan
    straight: bool  # every step since the last scan was straight walking
    anchor: FloatArray = field(
        metadata=shape(3)
    )  # [floor, x, y] of the last anchor passed (NaN: none)
    anchor_steps: int  # steps since it
    anchor_walked_m: float  # uncorrected PDR distance since it
    anchor_straight: bool  # every step since it was straight walking


def initial_state(params: EverywhereParams) -> EverywhereState:
    return EverywhereState(
        tracker=initial_tracker(params.tracker),
        x=np.zeros(4),
        P=np.diag([params.min_fix_var_m2] * 2 + [params.p0_scale, math.pi**2]),
        fp=np.full((2, 2), np.nan),
        walked_m=0.0,
        straight=False,
        anchor=np.full(3, np.nan),
        anchor_steps=0,
        anchor_walked_m=0.0,
        anchor_straight=False,
    )


def step_motion(x: FloatArray, length_m: float, turn_rad: float) -> tuple[FloatArray, FloatArray]:
    """Eq 15 for one step of PDR length ``length_m`` after a turn of ``turn_rad``: the
    predicted state and the transition matrix of eq 16 (its Jacobian)."""
    d = length_m
    scale, h = 1.0 + x[2], x[3] + turn_rad
    s, c = math.sin(h), math.cos(h)
    A = np.array(
        [
            [1.0, 0.0, d * s, scale * d * c],
            [0.0, 1.0, d * c, -scale * d * s],
            [0.0, 0.0, 1.0, 0.0],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    x_pred = np.array([x[0] + scale * d * s, x[1] + scale * d * c, x[2], wrap_angle(h)])
    return x_pred, A


def _on_step(
    state: EverywhereState,
    step: Step,
    maps: SiteMaps,
    params: EverywhereParams,
    rng: np.random.Generator,
) -> tuple[EverywhereState, Fix | None]:
    del rng  # deterministic
    state = replace(
        state,
        walked_m=state.walked_m + step.length_m * (1.0 + float(state.x[2])),
        straight=state.straight and step.straight,
        anchor_steps=state.anchor_steps + 1,
        anchor_walked_m=state.anchor_walked_m + step.length_m,
        anchor_straight=state.anchor_straight and step.straight,
    )
    d = step.length_m
    new = pdr_kalman.predict_step(
        state,
        step,
        maps,
        params,
        (1.0 + float(state.x[2])) * d,
        lambda x, turn_rad: step_motion(x, d, turn_rad),
        params.process_noise,
    )
    if not new.initialized:
        return new, None
    x = new.x
    return new, pdr_kalman.state_fix(
        new, step.t_ms, "step", {"step_length_m": float((1.0 + x[2]) * d)}
    )


def aiding_penalty(
    rp: FloatArray, fp: FloatArray, walked_m: float, params: EverywhereParams
) -> FloatArray:
    """``ξ_Δd + ξ_ΔH`` per reference (at ``rp``, ``papers/003_*`` eq 13-14), weighted to
    dB.

    ``fp`` holds the fingerprint positions at t-2 and t-1; ``walked_m`` the PDR distance
    since t-1.
    """
    to_rp = rp - fp[1]
    xi_d = np.abs(np.hypot(to_rp[:, 0], to_rp[:, 1]) - walked_m)  # eq 13
    walking = fp[1] - fp[0]
    bearing_walk = math.atan2(float(walking[0]), float(walking[1]))
    bearing_rp = np.arctan2(to_rp[:, 0], to_rp[:, 1])
    xi_h = np.abs(wrap_angle(bearing_rp - bearing_walk))  # eq 14, wrapped
    penalty: FloatArray = params.aid_distance_db_per_m * xi_d + params.aid_heading_db_per_rad * xi_h
    return penalty


def _select(
    state: EverywhereState, m: scan_fixes.Matched, maps: SiteMaps, params: EverywhereParams
) -> tuple[scan_fixes.Matched, dict[str, float]]:
    """The PDR-aided selection (eq 11-14) after straight walking from two known
    fingerprint positions, else the whole-map fix."""
    if not (state.straight and state.walked_m > 0.0 and not np.isnan(state.fp).any()):
        return m, {}
    penalty = aiding_penalty(scan_fixes.reference_xy(maps), state.fp, state.walked_m, params)
    return scan_fixes.constrained(maps, m, params, penalty_db=penalty), {"aided": 1.0}


def _remember_fp(
    state: EverywhereState, taken: pdr_kalman.Taken, params: EverywhereParams
) -> tuple[EverywhereState, dict[str, float]]:
    """The fix the filter took as the fingerprint position at t-1, the walk since it
    starting afresh."""
    del params  # the same for every walk
    found = taken.used.whole
    fp = np.array([state.fp[1], [found.x_m, found.y_m]])
    return replace(state, fp=fp, walked_m=0.0, straight=True), {}


def _on_scan(
    state: EverywhereState,
    event: Scan,
    maps: SiteMaps,
    params: EverywhereParams,
    rng: np.random.Generator,
) -> tuple[EverywhereState, Fix | None]:
    del rng  # deterministic
    if isinstance(event, BleEvent) and maps.anchors:
        state, anchor_fix = _on_anchor(state, event, maps, params)
        if anchor_fix is not None:
            return state, anchor_fix
    return pdr_kalman.scan_update(state, event, maps, params, _select, _remember_fp)


def _passed_anchor(maps: SiteMaps, event: BleEvent) -> int | None:
    """Index of the anchor whose beacon this scan hears at or above its threshold (the
    strongest such one); None when there is none."""
    heard = {radio_key("ble", r.emitter): r.rssi_dbm for r in event.readings}
    best: tuple[float, int] | None = None
    for i, anchor in enumerate(maps.anchors):
        rssi = heard.get(anchor.emitter)
        if rssi is not None and rssi >= anchor.rssi_dbm and (best is None or rssi > best[0]):
            best = (rssi, i)
    return None if best is None else best[1]


def _on_anchor(
    state: EverywhereState, event: BleEvent, maps: SiteMaps, params: EverywhereParams
) -> tuple[EverywhereState, Fix | None]:
    """Position (and, after a straight walk from the previous anchor, step length and
    heading) update at an anchor (``papers/003_*`` eq 18-21)."""
    index = _passed_anchor(maps, event)
    if index is None:
        return state, None
    anchor: Anchor = maps.anchors[index]
    here = np.array([anchor.floor, anchor.x_m, anchor.y_m], dtype=np.float64)
    if np.array_equal(here, state.anchor):
        return state, None  # still at the anchor passed last
    diagnostics = {"anchor": float(index)}
    x, P = state.x, state.P
    if state.initialized and state.heading_known and not np.isnan(state.anchor).any():
        previous = Anchor(int(state.anchor[0]), float(state.anchor[1]), float(state.anchor[2]), "")
        if (
            state.anchor_straight
            and state.anchor_steps >= params.anchor_min_steps
            and previous.floor == anchor.floor
        ):
            true_m = math.hypot(anchor.x_m - previous.x_m, anchor.y_m - previous.y_m)
            # eq 18-19: the calibrated step over the PDR step, as a correction of s
            scale = true_m / state.anchor_walked_m - 1.0
            u = update(x, P, z=[scale], H=_H_SCALE, R=np.array([[params.r_step_scale]]))
            x, P = u.x, u.P
            # eq 20-21: measured minus true bearing from the previous anchor
            bearing_true = math.atan2(anchor.x_m - previous.x_m, anchor.y_m - previous.y_m)
            bearing_meas = math.atan2(x[0] - previous.x_m, x[1] - previous.y_m)
            error = float(wrap_angle(bearing_meas - bearing_true))
            h = update(
                x,
                P,
                z=[float(wrap_angle(x[3] - error))],
                H=_H_HEADING,
                R=np.array([[params.r_anchor_heading_rad2]]),
                residual=lambda z, zp: wrap_angle(z - zp),
            )
            x, P = h.x, h.P
            x[3] = wrap_angle(x[3])
            diagnostics["step_scale"] = scale
            diagnostics["heading_error_rad"] = error
    if state.initialized:
        u = update(
            x,
            P,
            z=[anchor.x_m, anchor.y_m],
            H=scan_fixes.H_POSITION,
            R=params.anchor_var_m2 * np.eye(2),
        )
        x, P = u.x, u.P
    else:
        x, P = x.copy(), P.copy()
        x[:2] = anchor.x_m, anchor.y_m
        P[:2, :] = P[:, :2] = 0.0
        P[0, 0] = P[1, 1] = params.anchor_var_m2
    new = replace(
        state,
        x=x,
        P=P,
        floor=anchor.floor,
        initialized=True,
        rejects=0,
        anchor=here,
        anchor_steps=0,
        anchor_walked_m=0.0,
        anchor_straight=True,
    )
    return new, pdr_kalman.state_fix(new, event.t_ms, "anchor", diagnostics)


SPEC = EngineSpec(
    name="everywhere_ekf",
    params_type=EverywhereParams,
    state_type=EverywhereState,
    initial_state=initial_state,
    uses=pdr_kalman.USES,
    handlers=pdr_kalman.routes(_on_step, _on_scan),
    prepass=with_found_steps,
)
