"""``step_ekf``: a position EKF driven by phone steps and corrected by WiFi/BLE WKNN fixes.

State (``papers/002_*`` eq 18): ``B = [x, y, S, psi]`` -- position (m, in the building's
frame: x east, y north before its rotation), step length S (m) and heading psi (rad,
clockwise from the building's y axis: the phone's heading from north less the building's
rotation, ``scan_fixes.in_building_frame``).

Prediction at each step event (``papers/002_*`` eq 21, in the form of ``papers/003_*``
eq 15, which moves with the heading *after* the step's turn)::

    psi_k = psi_{k-1} + dpsi_k
    x_k   = x_{k-1} + S_{k-1} sin(psi_k)
    y_k   = y_{k-1} + S_{k-1} cos(psi_k)
    S_k   = S_{k-1}

where ``dpsi_k`` is the change of the phone heading since the previous step, wrapped to
(-pi, pi]. Cui writes eq 21 as ``x += S cos(pi - psi_C)``, ``y += S sin(pi - psi_C)``; with
our clockwise-from-north heading psi that is ``psi_C = psi + pi/2`` (Cui's eq 19 start
value ``psi_C = pi/2`` is our north). The Jacobian (``papers/003_*`` eq 16 with our state)
is::

    F = [[1, 0, sin(psi_k),  S cos(psi_k)],
         [0, 1, cos(psi_k), -S sin(psi_k)],
         [0, 0, 1,           0           ],
         [0, 0, 0,           1           ]]

and the process noise is ``Q = diag(q_x, q_y, q_S, q_psi)`` per step (``papers/002_*``
eq 22). The initial covariance uses ``papers/002_*`` eq 20 for S and psi.

Measurements (``papers/002_*`` eq 23-24, ``C = B + u``, split by source):

* every step: its length and heading measure ``S`` and ``psi`` (``H`` selects S and psi;
  the heading innovation is wrapped to (-pi, pi]);
* every WiFi/BLE scan: the WKNN position (``papers/002_*`` eq 1-3, see
  ``server.positioning.radio.fingerprints``, floor from the floor filter) measures ``x, y``
  with ``R = var * I``, ``var`` the fix's learned variance (``scan_fixes.match``).

Cui's measurement covariance ``R2 = diag(1000, 1000, 10, 100)`` (``papers/002_*`` eq 25)
is on a scale that does not fit metres and radians (a 1000 m^2 position variance would
make WiFi useless; a 100 rad^2 heading variance is more than a uniform heading), so it is
not used. Instead the step length and phone heading get their own variances
(``r_step_m2``, ``r_heading_rad2``) and each WiFi/BLE fix the variance its evidence is
worth on the map (eq 17 has the units of metres and shrinks with K: ``fingerprints``).

Robustness: a WiFi/BLE position whose squared Mahalanobis distance exceeds ``gate_chi2``
(chi-square, 2 dof) is rejected; after ``max_rejects`` consecutive rejections the filter
re-initialises at the fix, keeping S and psi. A fix on another floor than the filter's
re-initialises the same way (a floor change). Before the first WiFi/BLE fix the filter is
uninitialised: steps only record their heading, so the first fix starts with a known
heading when a step came before it. When the filter starts without a heading, the next
step sets psi to that step's heading (variance ``p0_heading_rad2``) before its prediction.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared import pdr_kalman, phone_steps, scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, with_floor_changes
from server.positioning.filters.kalman import predict_ekf, update, wrap_angle
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Fix, StepEvent, WifiEvent
from server.positioning.model.params import NonNegative, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion.barometer import BaroState, initial_barometer
from server.positioning.radio.fingerprints import WknnFix

FloatArray = NDArray[np.float64]

H_POSITION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
_H_STEP = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class StepEkfParams(pdr_kalman.KalmanParams):
    """Parameters of the ``step_ekf`` engine (paper defaults where the paper gives one);
    the position noise, gate and restart are ``KalmanParams``'s (as in two_stage_ekf:
    inner validation IPIN P75 14.7 against 16.7 m with 0.1 m² rather than 0.01, ILC site2
    mean 14.3 against 14.2 m; bench/accuracy.md)."""

    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.75, 0.80, 1.65, 3.60))

    q_step_m2: NonNegative = 0.0001  # process noise on S per step, papers/002_* eq 22
    p0_step_m2: Positive = 0.01  # initial variance of S, papers/002_* eq 20
    p0_heading_rad2: Positive = 0.01  # initial variance of a known psi, papers/002_* eq 20
    p0_heading_unknown_rad2: Positive = math.pi**2  # initial variance of psi when unknown
    initial_step_m: Positive = 0.7  # initial S (papers/002_* eq 19 starts at 0.6 m)
    r_step_m2: Positive = 0.01  # variance of the phone's step length (replaces eq 25 R2)
    r_heading_rad2: Positive = math.radians(10.0) ** 2  # phone heading variance (replaces eq 25)

    @property
    def process_noise(self) -> FloatArray:
        """Process noise covariance per step, shape (4, 4) (``papers/002_*`` eq 22)."""
        return self.noise(self.q_step_m2)


@dataclass(frozen=True, kw_only=True)
class StepEkfState:
    """State of one ``step_ekf`` session.

    Attributes
    ----------
    x : ndarray, shape (4,), float64
        ``[x_m, y_m, step_m, heading_rad]``.
    P : ndarray, shape (4, 4), float64
        Covariance of ``x``.
    floor : int
        Floor index of the estimate; -1 while uninitialised.
    initialized : bool
        False until the first WiFi/BLE fix.
    last_t_ms : int
        Time of the last step or scan event processed (0 before any).
    last_step_heading_rad : float
        Phone heading of the previous step; NaN when no step has been seen (since
        an initialisation without heading).
    rejects : int
        Consecutive WiFi/BLE positions rejected by the gate.
    """

    x: FloatArray = field(metadata=shape(4))
    P: FloatArray = field(metadata=shape(4, 4))
    floor: int
    initialized: bool
    last_t_ms: int
    last_step_heading_rad: float
    rejects: int
    # the floor filter after its last scan (empty: none yet)
    floor_logp: FloatArray = field(default_factory=lambda: scan_fixes.EMPTY)
    floor_t_ms: int = 0  # time of that scan
    baro: BaroState = field(default_factory=initial_barometer)  # floor changes by pressure


def initial_state(params: StepEkfParams) -> StepEkfState:
    """An uninitialised state: no position until the first WiFi/BLE fix."""
    return StepEkfState(
        x=np.array([0.0, 0.0, params.initial_step_m, 0.0]),
        P=np.diag(
            [
                params.min_fix_var_m2,
                params.min_fix_var_m2,
                params.p0_step_m2,
                params.p0_heading_unknown_rad2,
            ]
        ),
        floor=-1,
        initialized=False,
        last_t_ms=0,
        last_step_heading_rad=math.nan,
        rejects=0,
    )


def _step_residual(z: FloatArray, z_pred: FloatArray) -> FloatArray:
    y = z - z_pred
    y[1] = wrap_angle(y[1])
    return y


def state_fix(state: StepEkfState, t_ms: int, source: str, diagnostics: dict[str, float]) -> Fix:
    heading_known = not math.isnan(state.last_step_heading_rad)
    return scan_fixes.to_fix(
        state.x, state.P, state.floor, heading_known, t_ms, source, diagnostics, state.floor_logp
    )


def _start(
    state: StepEkfState, fix: WknnFix, var_m2: float, t_ms: int, params: StepEkfParams
) -> StepEkfState:
    """Place the filter at a fix. An initialised filter keeps S, psi and their covariance;
    a new one starts with ``initial_step_m`` and the last step heading (if any)."""
    P = np.zeros((4, 4))
    P[0, 0] = P[1, 1] = var_m2
    if state.initialized:
        motion = state.x[2:]
        P[2:, 2:] = state.P[2:, 2:]
    else:
        known = not math.isnan(state.last_step_heading_rad)
        motion = np.array([params.initial_step_m, state.last_step_heading_rad if known else 0.0])
        P[2, 2] = params.p0_step_m2
        P[3, 3] = params.p0_heading_rad2 if known else params.p0_heading_unknown_rad2
    return replace(
        state,
        x=np.concatenate([[fix.x_m, fix.y_m], motion]),
        P=P,
        floor=fix.floor,
        initialized=True,
        last_t_ms=t_ms,
        rejects=0,
    )


def on_step(
    state: StepEkfState,
    event: StepEvent,
    maps: SiteMaps,
    params: StepEkfParams,
    rng: np.random.Generator,
) -> tuple[StepEkfState, Fix | None]:
    """A phone step: the prediction, then its length and heading as measurements (module
    docstring); a fix once initialised."""
    del rng  # deterministic
    if not (math.isfinite(event.length_m) and math.isfinite(event.heading_rad)):
        return replace(state, last_t_ms=event.t_ms), None
    heading = float(wrap_angle(event.heading_rad))  # the phone's, from north
    if not state.initialized:
        return replace(state, last_t_ms=event.t_ms, last_step_heading_rad=heading), None

    # the filter's heading is in the building's frame; a turn is the same in both
    along = scan_fixes.in_building_frame(maps, state.floor, heading)
    x, P = state.x, state.P
    if math.isnan(state.last_step_heading_rad):
        # started without a heading: psi is uncorrelated with the rest, take this step's
        x = x.copy()
        P = P.copy()
        x[3] = along
        P[3, :] = P[:, 3] = 0.0
        P[3, 3] = params.p0_heading_rad2
        turn = 0.0
    else:
        turn = float(wrap_angle(heading - state.last_step_heading_rad))

    x_pred, F = pdr_kalman.step_motion(x, turn)
    x, P = predict_ekf(x_pred, P, F, params.process_noise)

    u = update(
        x,
        P,
        z=[event.length_m, along],
        H=_H_STEP,
        R=np.diag([params.r_step_m2, params.r_heading_rad2]),
        residual=_step_residual,
    )
    x = u.x
    x[3] = wrap_angle(x[3])
    new = replace(state, x=x, P=u.P, last_t_ms=event.t_ms, last_step_heading_rad=heading)
    return new, state_fix(new, event.t_ms, "step", {"step_length_m": float(x[2])})


P = TypeVar("P", bound=StepEkfParams)
# the variance of a scan's position fix, and what to report of how it was found
FixVariance = Callable[[scan_fixes.Matched, SiteMaps, P], tuple[float, dict[str, float]]]


def learned_variance(
    m: scan_fixes.Matched, maps: SiteMaps, params: StepEkfParams
) -> tuple[float, dict[str, float]]:
    """What a fix of this kind and evidence is worth on the map (``scan_fixes.match``)."""
    del maps, params
    return m.var_m2, {}


def on_scan(
    state: StepEkfState,
    event: WifiEvent | BleEvent,
    maps: SiteMaps,
    params: StepEkfParams,
    rng: np.random.Generator,
) -> tuple[StepEkfState, Fix | None]:
    """A WiFi/BLE scan's position update with the learned variance of its fix."""
    del rng  # deterministic
    return scan_update(state, event, maps, params, learned_variance)


def scan_update(
    state: StepEkfState,
    event: WifiEvent | BleEvent,
    maps: SiteMaps,
    params: P,
    variance: FixVariance[P],
) -> tuple[StepEkfState, Fix | None]:
    """A scan's position update with the variance of its fix from ``variance`` (the
    learned one here; ``fai_ekf``: the fingerprinting accuracy indicators): a fix when
    it was accepted or (re)started the filter."""
    state, m = scan_fixes.scan_matched(state, event, maps, params)
    if m is None:
        return state, None
    kind, found = m.kind, m.whole
    var_m2, reported = variance(m, maps, params)
    diagnostics = {"fix_var_m2": var_m2, "n_matched": float(m.n_matched), **reported}

    if not state.initialized or found.floor != state.floor:
        if state.initialized:
            diagnostics["floor_change"] = 1.0
        new = _start(state, found, var_m2, event.t_ms, params)
        return new, state_fix(new, event.t_ms, kind, diagnostics)

    u = update(state.x, state.P, z=[found.x_m, found.y_m], H=H_POSITION, R=var_m2 * np.eye(2))
    diagnostics["mahalanobis2"] = u.mahalanobis2
    if u.mahalanobis2 > params.gate_chi2:
        rejects = state.rejects + 1
        if rejects < params.max_rejects:
            return replace(state, last_t_ms=event.t_ms, rejects=rejects), None
        diagnostics["reinitialised"] = 1.0
        new = _start(state, found, var_m2, event.t_ms, params)
        return new, state_fix(new, event.t_ms, kind, diagnostics)

    new = replace(state, x=u.x, P=u.P, last_t_ms=event.t_ms, rejects=0)
    return new, state_fix(new, event.t_ms, kind, diagnostics)


# a batch in time order (stably); magnetometer events are ignored, deterministic. One fix
# per step once initialised and one per accepted or re-initialising scan.
SPEC = EngineSpec(
    name="step_ekf",
    params_type=StepEkfParams,
    state_type=StepEkfState,
    initial_state=initial_state,
    uses=phone_steps.USES,
    handlers=phone_steps.routes(on_step, on_scan, scan_fixes.on_floor_change),
    prepass=with_floor_changes,
)
