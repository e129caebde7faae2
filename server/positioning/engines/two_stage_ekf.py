"""``two_stage_ekf``: Cui et al.'s WiFi/MEMS integration from raw phone sensors.

Stage one (``papers/002_*`` section 6.1, eq 9-17) is the attitude-determination EKF of
``server.positioning.attitude``: gyro-driven Euler angles corrected by gravity, whose yaw
gives the phone heading. Steps come from the smoothed-magnitude peak detector
(``papers/002_*`` eq 5-7) with Weinberg step lengths (eq 8), see ``server.positioning.pdr``.

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
turn labels of ``server.positioning.pdr``) and the four positions span at least
``min_heading_span_m``. Until the first WiFi heading the map-frame heading is unknown:
steps then only widen the position variance by ``S²`` instead of moving the estimate.

Cui's ``R_2 = diag(1000, 1000, 10, 100)`` (eq 25) does not fit metres and radians, so the
measurement variances are our own (see ``server.positioning.engines.step_ekf`` for the
reasoning); ``Q_2`` and the initial ``S = 0.6 m`` are the paper's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from server.positioning import pdr
from server.positioning.engines.base import EngineSpec, SiteMaps
from server.positioning.events import BleEvent, Event, Fix, ImuEvent, WifiEvent
from server.positioning.fingerprint import WknnFix, scan_vector, wknn
from server.positioning.kalman import predict_ekf, update, wrap_angle
from server.positioning.step_tracker import (
    StepBlock,
    TrackerParams,
    TrackerState,
    initial_tracker,
    track,
)

FloatArray = NDArray[np.float64]

_H_POSITION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])
_H_STEP = np.array([[0.0, 0.0, 1.0, 0.0]])
_H_HEADING = np.array([[0.0, 0.0, 0.0, 1.0]])


def _cui_tracker() -> TrackerParams:
    return TrackerParams(
        heading="attitude", steps=pdr.PdrParams(detector="cui", length_model="weinberg")
    )


@dataclass(frozen=True)
class TwoStageParams:
    tracker: TrackerParams = field(default_factory=_cui_tracker)
    k: int = 4  # WKNN neighbours, papers/002_* eq 3
    partition_radius_m: float = 2.5  # papers/002_* section 4.1
    q_x_m2: float = 0.01  # papers/002_* eq 22
    q_y_m2: float = 0.01
    q_step_m2: float = 0.0001
    q_heading_rad2: float = 0.01
    initial_step_m: float = 0.6  # papers/002_* eq 19
    p0_step_m2: float = 0.01  # papers/002_* eq 20
    r_step_m2: float = 0.01  # variance of the Weinberg length as a measurement of S
    r_wifi_heading_rad2: float = math.radians(20.0) ** 2
    heading_fixes: int = 4  # papers/002_* section 4.2
    min_heading_span_m: float = 3.0
    min_fix_var_m2: float = 4.0  # as in step_ekf
    gate_chi2: float = 13.82  # chi2(2 dof), 99.9 %
    max_rejects: int = 3
    floor_memory: float = 0.7  # decay per scan of the floor votes
    floor_margin: float = 1.0  # vote lead another floor needs over ours to move there

    def __post_init__(self) -> None:
        if self.k < 1 or self.max_rejects < 1 or self.heading_fixes < 2:
            raise ValueError("k and max_rejects must be >= 1 and heading_fixes >= 2")
        for name in ("partition_radius_m", "min_fix_var_m2", "gate_chi2", "r_step_m2"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be positive and finite, got {value}")

    @property
    def process_noise(self) -> FloatArray:
        return np.diag([self.q_x_m2, self.q_y_m2, self.q_step_m2, self.q_heading_rad2])


@dataclass(frozen=True)
class TwoStageState:
    tracker: TrackerState
    x: FloatArray  # [x_m, y_m, step_m, heading_rad]
    P: FloatArray
    floor: int
    initialized: bool
    heading_known: bool
    last_phone_heading: float  # phone heading of the previous step (NaN before any)
    rejects: int
    fixes: FloatArray  # (heading_fixes, 3) [t_ms, x, y] of recent WKNN positions, NaN-padded
    turn_t_ms: float  # time of the last step that was not straight walking
    floor_votes: FloatArray  # decayed whole-map floor votes per floor index

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"trk." + k: v for k, v in self.tracker.to_arrays().items()}
        out.update(
            x=self.x,
            P=self.P,
            floor=np.array(self.floor),
            initialized=np.array(self.initialized, dtype=np.int8),
            heading_known=np.array(self.heading_known, dtype=np.int8),
            last_phone_heading=np.array(self.last_phone_heading),
            rejects=np.array(self.rejects),
            fixes=self.fixes,
            turn_t_ms=np.array(self.turn_t_ms),
            floor_votes=self.floor_votes,
        )
        return out

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> TwoStageState:
        tracker = {k[4:]: v for k, v in arrays.items() if k.startswith("trk.")}
        x = np.array(arrays["x"], dtype=np.float64)
        P = np.array(arrays["P"], dtype=np.float64)
        if x.shape != (4,) or P.shape != (4, 4):
            raise ValueError("two_stage_ekf state needs x (4,) and P (4, 4)")
        return cls(
            tracker=TrackerState.from_arrays(tracker),
            x=x,
            P=P,
            floor=int(arrays["floor"]),
            initialized=bool(arrays["initialized"]),
            heading_known=bool(arrays["heading_known"]),
            last_phone_heading=float(arrays["last_phone_heading"]),
            rejects=int(arrays["rejects"]),
            fixes=np.array(arrays["fixes"], dtype=np.float64),
            turn_t_ms=float(arrays["turn_t_ms"]),
            floor_votes=np.array(arrays["floor_votes"], dtype=np.float64),
        )


def initial_state(params: TwoStageParams) -> TwoStageState:
    return TwoStageState(
        tracker=initial_tracker(params.tracker),
        x=np.array([0.0, 0.0, params.initial_step_m, 0.0]),
        P=np.diag([params.min_fix_var_m2] * 2 + [params.p0_step_m2, math.pi**2]),
        floor=-1,
        initialized=False,
        heading_known=False,
        last_phone_heading=math.nan,
        rejects=0,
        fixes=np.full((params.heading_fixes, 3), np.nan),
        turn_t_ms=-math.inf,
        floor_votes=np.zeros(0),
    )


def _fix(state: TwoStageState, t_ms: int, source: str, diagnostics: dict[str, float]) -> Fix:
    c = state.P[:2, :2]
    return Fix(
        t_ms=t_ms,
        x_m=float(state.x[0]),
        y_m=float(state.x[1]),
        floor=state.floor,
        heading_rad=float(state.x[3]) if state.heading_known else None,
        cov=(float(c[0, 0]), float(c[0, 1]), float(c[1, 0]), float(c[1, 1])),
        source=source,
        diagnostics=diagnostics,
    )


def _on_step(
    state: TwoStageState,
    t_ms: int,
    length_m: float,
    phone_heading: float,
    straight: bool,
    params: TwoStageParams,
) -> tuple[TwoStageState, Fix | None]:
    turn = 0.0
    if math.isfinite(phone_heading) and math.isfinite(state.last_phone_heading):
        turn = float(wrap_angle(phone_heading - state.last_phone_heading))
    state = replace(
        state,
        last_phone_heading=phone_heading
        if math.isfinite(phone_heading)
        else state.last_phone_heading,
        turn_t_ms=state.turn_t_ms if straight else float(t_ms),
    )
    if not state.initialized:
        return state, None
    x, P = state.x.copy(), state.P.copy()
    if not state.heading_known:
        # no map-frame heading yet: the step could go anywhere within S of here
        x[3] = wrap_angle(x[3] + turn)
        P[0, 0] += x[2] ** 2
        P[1, 1] += x[2] ** 2
    else:
        step, psi = x[2], x[3] + turn
        s, c = math.sin(psi), math.cos(psi)
        F = np.array(
            [
                [1.0, 0.0, s, step * c],
                [0.0, 1.0, c, -step * s],
                [0.0, 0.0, 1.0, 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        x_pred = np.array([x[0] + step * s, x[1] + step * c, step, wrap_angle(psi)])
        x, P = predict_ekf(x_pred, P, F, params.process_noise)
    u = update(x, P, z=[length_m], H=_H_STEP, R=np.array([[params.r_step_m2]]))
    new = replace(state, x=u.x, P=u.P)
    return new, _fix(new, t_ms, "step", {"step_length_m": float(u.x[2])})


def _partition(maps: SiteMaps, state: TwoStageState, radius_m: float) -> NDArray[np.bool_]:
    assert maps.radio is not None
    rp = maps.radio.rp_xy.astype(np.float64)
    near = np.hypot(rp[:, 0] - state.x[0], rp[:, 1] - state.x[1]) <= radius_m
    mask: NDArray[np.bool_] = near & (maps.radio.rp_floor == state.floor)
    return mask


def _wifi_heading(fixes: FloatArray, turn_t_ms: float, min_span_m: float) -> float | None:
    """Direction of the least-squares line through the recent WKNN positions, oriented
    from the oldest to the newest (``papers/002_*`` section 4.2)."""
    if np.isnan(fixes).any() or turn_t_ms >= fixes[0, 0]:
        return None
    xy = fixes[:, 1:]
    centred = xy - xy.mean(axis=0)
    vt = np.linalg.svd(centred)[2]
    direction = vt[0]
    along = centred @ direction
    if along[-1] - along[0] < 0:
        direction = -direction
    if float(np.ptp(along)) < min_span_m:
        return None
    return math.atan2(float(direction[0]), float(direction[1]))


def _restart(
    state: TwoStageState, found: WknnFix, var_m2: float, params: TwoStageParams
) -> TwoStageState:
    x = state.x.copy()
    P = state.P.copy()
    x[:2] = found.x_m, found.y_m
    P[:2, :] = P[:, :2] = 0.0
    P[0, 0] = P[1, 1] = var_m2
    if not state.initialized:
        x[2] = params.initial_step_m
        P[2, 2] = params.p0_step_m2
    return replace(state, x=x, P=P, floor=found.floor, initialized=True, rejects=0)


def _on_scan(
    state: TwoStageState,
    t_ms: int,
    readings: WifiEvent | BleEvent,
    kind: str,
    maps: SiteMaps,
    params: TwoStageParams,
) -> tuple[TwoStageState, Fix | None]:
    if maps.radio is None:
        return state, None
    scan = scan_vector(maps.radio, readings.readings, kind)
    whole = wknn(maps.radio, scan, k=params.k)
    if whole is None:
        return state, None
    diagnostics = {"n_matched": float(scan.n_matched)}
    votes = np.zeros(max(len(maps.floors), whole.floor + 1, state.floor_votes.size))
    votes[: state.floor_votes.size] = params.floor_memory * state.floor_votes
    votes[whole.floor] += 1.0
    state = replace(state, floor_votes=votes)
    if state.initialized and whole.floor != state.floor:
        # another floor: move only when it leads the recent votes, else stay on ours
        leader = int(np.argmax(votes))
        if leader != state.floor and votes[leader] - votes[state.floor] >= params.floor_margin:
            diagnostics["floor_change"] = 1.0
            if leader != whole.floor:
                return state, None
        else:
            on_floor = wknn(
                maps.radio, scan, k=params.k, candidates=maps.radio.rp_floor == state.floor
            )
            if on_floor is None:
                return state, None
            whole = on_floor
    if not state.initialized or whole.floor != state.floor:
        var = max(whole.var_m2, params.min_fix_var_m2)
        new = _restart(state, whole, var, params)
        new = _remember(new, t_ms, whole)
        return new, _fix(new, t_ms, kind, diagnostics)

    # lost? the whole-map fix has failed the gate too many times in a row
    whole_var = max(whole.var_m2, params.min_fix_var_m2)
    check = update(
        state.x, state.P, z=[whole.x_m, whole.y_m], H=_H_POSITION, R=whole_var * np.eye(2)
    )
    rejects = state.rejects + 1 if check.mahalanobis2 > params.gate_chi2 else 0
    if rejects >= params.max_rejects:
        diagnostics["reinitialised"] = 1.0
        new = _remember(_restart(state, whole, whole_var, params), t_ms, whole)
        return new, _fix(new, t_ms, kind, diagnostics)

    found = wknn(
        maps.radio, scan, k=params.k, candidates=_partition(maps, state, params.partition_radius_m)
    )
    diagnostics["partition"] = 1.0 if found is not None else 0.0
    found = found or whole
    var = max(found.var_m2, params.min_fix_var_m2)
    u = update(state.x, state.P, z=[found.x_m, found.y_m], H=_H_POSITION, R=var * np.eye(2))
    diagnostics["mahalanobis2"] = u.mahalanobis2
    state = _remember(replace(state, x=u.x, P=u.P, rejects=rejects), t_ms, whole)

    heading = _wifi_heading(state.fixes, state.turn_t_ms, params.min_heading_span_m)
    if heading is not None:
        diagnostics["wifi_heading_rad"] = heading
        if not state.heading_known:
            x, P = state.x.copy(), state.P.copy()
            x[3] = heading
            P[3, :] = P[:, 3] = 0.0
            P[3, 3] = params.r_wifi_heading_rad2
            state = replace(state, x=x, P=P, heading_known=True)
        else:
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
    return state, _fix(state, t_ms, kind, diagnostics)


def _remember(state: TwoStageState, t_ms: int, found: WknnFix) -> TwoStageState:
    fixes = np.roll(state.fixes, -1, axis=0)
    fixes[-1] = t_ms, found.x_m, found.y_m
    return replace(state, fixes=fixes)


def run(
    state: TwoStageState,
    events: Sequence[Event],
    maps: SiteMaps,
    params: TwoStageParams,
    rng: np.random.Generator,
) -> tuple[TwoStageState, list[Fix]]:
    """Process a batch: raw IMU blocks become steps, then steps and scans in time order.

    Step events sent by the phone are ignored: this engine finds its own steps.
    """
    del rng  # deterministic
    tracker = state.tracker
    blocks: list[StepBlock] = []
    imus = [e for e in events if isinstance(e, ImuEvent)]
    for imu in sorted(imus, key=lambda e: e.t_ms):
        tracker, block = track(tracker, imu, params.tracker)
        blocks.append(block)
    state = replace(state, tracker=tracker)

    timeline: list[tuple[int, int, object]] = []
    for block in blocks:
        for i in range(len(block)):
            row = (
                float(block.length_m[i]),
                float(block.heading_rad[i]),
                block.status[i] == pdr.STRAIGHT,
            )
            timeline.append((int(block.t_ms[i]), 0, row))
    for event in events:
        if isinstance(event, WifiEvent | BleEvent):
            timeline.append((event.t_ms, 1, event))
    timeline.sort(key=lambda item: (item[0], item[1]))

    fixes: list[Fix] = []
    for t_ms, _, item in timeline:
        fix: Fix | None
        if isinstance(item, tuple):
            length, heading, straight = item
            state, fix = _on_step(state, t_ms, length, heading, straight, params)
        elif isinstance(item, WifiEvent):
            state, fix = _on_scan(state, t_ms, item, "wifi", maps, params)
        else:
            assert isinstance(item, BleEvent)
            state, fix = _on_scan(state, t_ms, item, "ble", maps, params)
        if fix is not None:
            fixes.append(fix)
    return state, fixes


SPEC = EngineSpec(
    name="two_stage_ekf",
    params_type=TwoStageParams,
    initial_state=initial_state,
    from_arrays=TwoStageState.from_arrays,
    run=run,
    uses=frozenset({"imu", "wifi", "ble"}),
)
