"""``map_markov``: WiFi fingerprints tracked over the floor's reference-point Markov chain,
a constant-velocity Kalman filter and the phone's steps (Wang et al., ``papers/004_*``).

Per WiFi/BLE scan (Algorithm 3, "Integration track"):

1. the scan is matched on the whole map (``scan_fixes.match``: strongest signals,
   floor filter, WKNN; eq 4-6 with the floor chosen as every engine here chooses it);
   a session starts there, and restarts there on a floor change or when lost;
2. prediction. The belief over the floor graph's vertices (``navigation_graph``,
   ``markov_chain``) moves by as many hops as the walker can have gone since the last
   scan: the steps' length (times the personal scale) plus ``slack_m``, or
   ``max_speed_mps`` times the time without steps, in the steps' direction weighted by
   the reliability θ (eq 17-18). Where the belief's most probable vertex is a corridor
   one (not a corner, junction, door or room: Algorithm 3's "else"), the Kalman
   prediction narrows it: each vertex is weighed by a Gaussian around the predicted
   position. A belief found on another graph (the map changed) restarts at the vertex
   nearest the estimate;
3. the state space Ω is the set of reference points attached to the vertices the belief
   reached; each is weighed by the belief and the scan's likelihood (eq 14, ``sigma_db``),
   and S' is the weighted mean of the ``k`` most probable (the kNN of eq 5-6 over Ω);
   where the map has its surveyed scans, S' is the scan's match among those whose
   nearest vertex is in Ω (``scan_fixes.constrained``). When the best signal distance
   in Ω is ``gate_db`` worse than the whole map's best (on the scans: ``scan_gate_db``,
   their distance of ``scan_matching``), or Ω is empty, the scan is not used;
   ``max_rejects`` such scans in a row restart the session at the whole-map fix (the
   chain "cannot turn to the right state", as Wang notes under eq 15);
4. the Kalman filter over ``S = [x, y, vx, vy]`` (eq 7, 10-13, ``T_s`` the time since
   its last update, process noise ``q_accel`` of a white acceleration) predicts with
   eq 16: ``(1 - θ) A S + θ A U``, ``U`` the state with the steps' mean velocity; S'' is
   the position the steps alone give (the last estimate plus their displacement), and
   the filter is corrected with ``(1 - θ) S' + θ S''`` (Algorithm 3) at the scan's
   learned variance (``scan_fixes.match``).

Per step: the step moves the estimate by its length times the personal scale along its
heading (turned into the building frame); a fix per step. At a turn (the heading leaves
the straight segment's mean by more than ``turn_deg``) the Kalman velocity turns to the
new heading (Algorithm 3's reset), by θ: it becomes ``(1 - θ) v + θ v_turned``. With
``personalise`` (off by default: see ``MapMarkovParams``), Algorithm 2's map-based step
length: the distance walked along the segment (from its start to the estimate at the
turn, along the segment's heading) divided by the phone's summed step lengths over it
becomes the scale (within ``[min_step_scale, max_step_scale]``, after at least
``min_segment_steps`` steps and one scan).

θ = 0 leaves the scans alone (S = S', plain eq 12, moves by ``M`` without direction, no
reset: the step headings change nothing at the scans); θ = 1 leaves the steps alone. A
session that has never sent a step runs with θ = 0.
Defaults: θ = 0.6 (Table 2's best), Wang's T_s is the time between scans here.

Without a graph for the floor (no plan and no reference points) the belief is skipped:
Ω is the whole floor, and the engine is the Kalman filter over WKNN fixes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Annotated

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.engines.shared import phone_steps, scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, with_floor_changes
from server.positioning.filters import markov_chain as mc
from server.positioning.filters.kalman import update, wrap_angle
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Fix, StepEvent, WifiEvent
from server.positioning.model.params import AtLeastOne, NonNegative, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion.barometer import BaroState, FloorChange, initial_barometer
from server.positioning.plan.navigation_graph import CORRIDOR, FloorGraph
from server.positioning.radio.fingerprints import signal_distances

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

VELOCITY_WINDOW_S = 0.5  # the steps' velocity is read over at least this long

Reliability = Annotated[float, Ge(0.0), Le(1.0)]


@dataclass(frozen=True)
class MapMarkovParams(scan_fixes.RadioParams):
    """Parameters of the ``map_markov`` engine (Wang's where the paper gives one)."""

    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.85, 0.40, 1.30, 2.60))

    theta: Reliability = 0.6  # reliability of the inertial sensors, papers/004_* Table 2
    sigma_db: Positive = 8.0  # eq 14's sigma: the scan's confidence
    q_accel: NonNegative = 0.5  # white-acceleration noise of the eq 10 filter (m²/s³)
    v0_var: Positive = 1.0  # initial velocity variance (m²/s²)
    max_speed_mps: Positive = 1.5  # reach per second without steps
    slack_m: NonNegative = 2.0  # reach beyond the steps' length
    max_hops: AtLeastOne = 40
    max_states: AtLeastOne = 300  # belief beam
    gate_db: Positive = 10.0  # Ω's best signal distance this much worse: scan not used
    # the same where the map has its scans, on their distances (scan_matching). 1 dB
    # against the cells' 10: validation site2 12.16 -> 11.22 m, IPIN 20.77 -> 14.45 m,
    # score 33.47 -> 16.97 m (0.5, 2, 3, 6, 10, 20 dB in bench/accuracy.md)
    scan_gate_db: Positive = 1.0
    max_rejects: AtLeastOne = 3  # scans not used in a row before a restart
    # Algorithm 2's step length from the map at turns: off by default. The phones send
    # step lengths of their own, and on both validation splits it moved nothing beyond
    # noise (site2 mean / P75 15.15 / 18.80 m off, 15.20 / 18.72 m on; IPIN 17.20 / 19.52
    # against 17.41 / 19.71 m), while on a walk whose step lengths are right it costs
    # (tests); for steps of unknown length it is what Wang uses
    personalise: bool = False
    turn_deg: Positive = 45.0  # a heading this far off the segment's is a turn (Algorithm 2)
    min_segment_steps: AtLeastOne = 8
    min_step_scale: Positive = 0.75
    max_step_scale: Positive = 1.33


@dataclass(frozen=True, kw_only=True)
class MapMarkovState:
    """State of one ``map_markov`` session.

    ``x = [x, y, vx, vy]`` and ``P`` the Kalman filter after its last update at
    ``kf_t_ms``; ``dr_xy`` / ``dr_m`` the steps' displacement and length since then;
    ``belief_*`` the chain's belief (vertex ids, probabilities) on ``floor``'s graph.
    """

    x: FloatArray = field(metadata=shape(4))
    P: FloatArray = field(metadata=shape(4, 4))
    floor: int = -1
    initialized: bool = False
    last_t_ms: int = 0
    kf_t_ms: int = 0
    dr_xy: FloatArray = field(default_factory=lambda: np.zeros(2), metadata=shape(2))
    dr_m: float = 0.0
    steps_since: int = 0  # steps since kf_t_ms
    steps_seen: bool = False
    belief_vertex: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    belief_p: FloatArray = field(default_factory=lambda: scan_fixes.EMPTY)
    rejects: int = 0
    step_scale: float = 1.0
    segment_heading: float = math.nan  # building-frame heading of the straight segment
    segment_steps: int = 0
    segment_phone_m: float = 0.0  # the phone's step lengths summed over the segment
    segment_start: FloatArray = field(default_factory=lambda: np.zeros(2), metadata=shape(2))
    segment_scans: int = 0  # scans that corrected the estimate during the segment
    graph_key: int = 0  # FloorGraph.fingerprint of the graph the belief's ids are on
    floor_logp: FloatArray = field(default_factory=lambda: scan_fixes.EMPTY)
    floor_t_ms: int = 0
    baro: BaroState = field(default_factory=initial_barometer)  # floor changes by pressure


def initial_state(params: MapMarkovParams) -> MapMarkovState:
    """A state before any fix."""
    return MapMarkovState(x=np.zeros(4), P=np.eye(4) * params.v0_var)


def blend(theta: float, wifi: FloatArray, inertial: FloatArray) -> FloatArray:
    """``(1 - θ) wifi + θ inertial``: Algorithm 3's location and eq 16's prediction."""
    out: FloatArray = (1.0 - theta) * np.asarray(wifi) + theta * np.asarray(inertial)
    return out


def _at_most(v: FloatArray, speed: float) -> FloatArray:
    norm = float(np.linalg.norm(v))
    out: FloatArray = v * (speed / norm) if norm > speed else v
    return out


def _transition(dt_s: float) -> FloatArray:
    A = np.eye(4)
    A[0, 2] = A[1, 3] = dt_s  # papers/004_* eq 11
    return A


def _process_noise(dt_s: float, q: float) -> FloatArray:
    """White-acceleration noise over ``dt_s`` for one axis pair (eq 10's Q)."""
    Q = np.zeros((4, 4))
    for p, v in ((0, 2), (1, 3)):
        Q[p, p] = q * dt_s**3 / 3
        Q[p, v] = Q[v, p] = q * dt_s**2 / 2
        Q[v, v] = q * dt_s
    return Q


def _position(state: MapMarkovState) -> FloatArray:
    """The estimate now: the filter's position plus the steps since."""
    out: FloatArray = state.x[:2] + state.dr_xy
    return out


def _fix(state: MapMarkovState, t_ms: int, source: str, diag: dict[str, float]) -> Fix:
    xy = _position(state)
    c = state.P[:2, :2] + np.eye(2) * (0.1 * state.steps_since)
    x = np.array([xy[0], xy[1], 0.0, 0.0])
    P = np.zeros((4, 4))
    P[:2, :2] = c
    heading_known = not math.isnan(state.segment_heading)
    if heading_known:
        x[3] = state.segment_heading
    return scan_fixes.to_fix(x, P, state.floor, heading_known, t_ms, source, diag, state.floor_logp)


def _graph(maps: SiteMaps, floor: int) -> FloorGraph | None:
    return maps.graphs[floor] if 0 <= floor < len(maps.graphs) else None


def _start(
    state: MapMarkovState, m: scan_fixes.Matched, maps: SiteMaps, params: MapMarkovParams
) -> MapMarkovState:
    found = m.whole
    graph = _graph(maps, found.floor)
    belief = mc.Belief.at(graph.nearest([found.x_m, found.y_m])) if graph else None
    P = np.diag([m.var_m2, m.var_m2, params.v0_var, params.v0_var])
    return replace(
        state,
        x=np.array([found.x_m, found.y_m, 0.0, 0.0]),
        P=P,
        floor=found.floor,
        initialized=True,
        last_t_ms=m.t_ms,
        kf_t_ms=m.t_ms,
        dr_xy=np.zeros(2),
        dr_m=0.0,
        steps_since=0,
        belief_vertex=belief.vertex if belief else np.zeros(0, dtype=np.int64),
        belief_p=belief.p if belief else scan_fixes.EMPTY,
        graph_key=graph.fingerprint if graph else 0,
        rejects=0,
        segment_heading=math.nan,
        segment_steps=0,
        segment_phone_m=0.0,
        segment_scans=0,
        segment_start=np.array([found.x_m, found.y_m]),
    )


def on_step(
    state: MapMarkovState,
    event: StepEvent,
    maps: SiteMaps,
    params: MapMarkovParams,
    rng: np.random.Generator,
) -> tuple[MapMarkovState, Fix | None]:
    del rng  # deterministic
    if not (math.isfinite(event.length_m) and math.isfinite(event.heading_rad)):
        return replace(state, last_t_ms=event.t_ms), None
    if not state.initialized:
        return replace(state, last_t_ms=event.t_ms, steps_seen=True), None
    heading = scan_fixes.in_building_frame(maps, state.floor, event.heading_rad)
    here = _position(state)
    diag: dict[str, float] = {}
    x = state.x
    if math.isnan(state.segment_heading):
        state = _new_segment(state, heading, here, event.length_m)
    elif abs(float(wrap_angle(heading - state.segment_heading))) > math.radians(params.turn_deg):
        # a turn: Algorithm 2's step length from the map, Algorithm 3's filter reset
        scale = state.step_scale
        enough = state.segment_steps >= params.min_segment_steps and state.segment_scans > 0
        enough &= params.personalise
        if enough and state.segment_phone_m > 0:
            # the segment's length along its own heading (its sideways scatter would only
            # ever lengthen it)
            along = np.array([math.sin(state.segment_heading), math.cos(state.segment_heading)])
            ratio = float((here - state.segment_start) @ along) / state.segment_phone_m
            scale = min(max(ratio, params.min_step_scale), params.max_step_scale)
            diag["step_scale"] = scale
        speed = float(np.hypot(x[2], x[3]))
        turned = speed * np.array([math.sin(heading), math.cos(heading)])
        x = np.concatenate([x[:2], blend(params.theta, x[2:], turned)])
        state = _new_segment(replace(state, x=x, step_scale=scale), heading, here, event.length_m)
    else:
        n = state.segment_steps + 1
        mean = state.segment_heading + float(wrap_angle(heading - state.segment_heading)) / n
        state = replace(
            state,
            segment_heading=float(wrap_angle(mean)),
            segment_steps=n,
            segment_phone_m=state.segment_phone_m + event.length_m,
        )
    length = event.length_m * state.step_scale
    move = length * np.array([math.sin(heading), math.cos(heading)])
    new = replace(
        state,
        last_t_ms=event.t_ms,
        dr_xy=state.dr_xy + move,
        dr_m=state.dr_m + length,
        steps_since=state.steps_since + 1,
        steps_seen=True,
    )
    return new, _fix(new, event.t_ms, "step", {"step_length_m": length, **diag})


def _new_segment(
    state: MapMarkovState, heading: float, start: FloatArray, phone_m: float
) -> MapMarkovState:
    """A straight segment starting at ``start`` with its first step."""
    return replace(
        state,
        segment_heading=heading,
        segment_steps=1,
        segment_phone_m=phone_m,
        segment_scans=0,
        segment_start=start,
    )


def _prior(
    state: MapMarkovState,
    graph: FloorGraph,
    predicted: FloatArray,
    spread_m2: float,
    dt_s: float,
    theta: float,
    params: MapMarkovParams,
) -> mc.Belief:
    """Algorithm 3's prediction: the chain's moves, narrowed by the Kalman prediction off
    decision vertices."""
    if state.belief_vertex.size == 0:
        return mc.Belief.at(graph.nearest(predicted))
    belief = mc.Belief(state.belief_vertex, state.belief_p)
    if state.steps_seen:
        reach = state.dr_m + params.slack_m
        direction: FloatArray | None = state.dr_xy
    else:
        reach = params.max_speed_mps * dt_s + params.slack_m
        direction = None
    hops = min(params.max_hops, max(1, math.ceil(reach / graph.spacing_m)))
    moved = mc.move(graph, belief, direction, theta, hops, params.max_states)
    here = int(belief.vertex[np.argmax(belief.p)])
    if graph.kind[here] != CORRIDOR:
        return moved
    d2 = np.sum((graph.xy[moved.vertex] - predicted) ** 2, axis=1)
    p = moved.p * np.exp(-d2 / (2.0 * (spread_m2 + graph.spacing_m**2)))
    if not p.sum() > 0:
        return moved
    return mc.Belief(moved.vertex, p / p.sum())


def on_scan(
    state: MapMarkovState,
    event: WifiEvent | BleEvent,
    maps: SiteMaps,
    params: MapMarkovParams,
    rng: np.random.Generator,
) -> tuple[MapMarkovState, Fix | None]:
    """A WiFi/BLE scan through Algorithm 3 (module docstring): a fix when it starts the
    session (again: a floor change, ``max_rejects`` scans not used) or corrects it."""
    del rng  # deterministic
    state, m = scan_fixes.scan_matched(state, event, maps, params)
    if m is None:
        return state, None
    kind, found = m.kind, m.whole
    diag = {"fix_var_m2": m.var_m2, "n_matched": float(m.n_matched)}
    if not state.initialized or found.floor != state.floor:
        if state.initialized:
            diag["floor_change"] = 1.0
        new = _start(state, m, maps, params)
        return new, _fix(new, event.t_ms, kind, diag)

    theta = params.theta if state.steps_seen else 0.0
    dt_s = max(event.t_ms - state.kf_t_ms, 0) / 1000.0
    A = _transition(dt_s)
    if state.steps_seen and dt_s >= VELOCITY_WINDOW_S:
        inertial_v = state.dr_xy / dt_s
    else:  # too short a time to tell a speed from: the filter's own
        inertial_v = state.x[2:]
    U = np.concatenate([state.x[:2], _at_most(inertial_v, params.max_speed_mps)])
    x_pred = blend(theta, A @ state.x, A @ U)  # papers/004_* eq 16
    P_pred = A @ state.P @ A.T + _process_noise(dt_s, params.q_accel)
    inertial = _position(state) if state.steps_seen else x_pred[:2]  # S''

    graph = _graph(maps, state.floor)
    radio = maps.radio
    assert radio is not None  # scan_fixes.match found a fix
    belief: mc.Belief | None = None
    if graph is not None and graph.rp_vertex.shape[0] == radio.rp_xy.shape[0]:
        if state.graph_key != graph.fingerprint:  # a new map: the old vertex ids mean nothing
            seed = mc.Belief.at(graph.nearest(state.x[:2]))
            state = replace(
                state, belief_vertex=seed.vertex, belief_p=seed.p, graph_key=graph.fingerprint
            )
        spread = float(np.trace(P_pred[:2, :2])) / 2.0
        prior = _prior(state, graph, x_pred[:2], spread, dt_s, theta, params)
        in_omega = np.isin(graph.rp_vertex, prior.vertex)
        rps = np.flatnonzero(in_omega)
        if rps.size:
            dist = signal_distances(radio, m.scan, rps)
            at = np.searchsorted(prior.vertex, graph.rp_vertex[rps])
            rp_prior = prior.p[at]  # every RP of Ω sits on a vertex of the prior
            w = mc.correct(rp_prior, dist, params.sigma_db)  # papers/004_* eq 14
            diag["omega_rps"] = float(rps.size)
            if maps.scans is not None:  # S' and the gate from the map's scans within Ω
                omega = _in_omega(maps, m, graph, prior.vertex, params)
                gap = math.inf
                if omega is not None:
                    gap = float(omega.whole.distances_db.min() - m.whole.distances_db.min())
                diag["omega_scan_gap_db"] = gap
                used = gap <= params.scan_gate_db
            else:
                omega = None
                cells = scan_fixes.on_cells(maps, m, params)
                best = float(cells.distances_db.min()) if cells is not None else float(dist.min())
                diag["omega_gap_db"] = float(dist.min()) - best
                used = dist.min() - best <= params.gate_db
            if used:
                if omega is not None:
                    wifi = np.array([omega.whole.x_m, omega.whole.y_m])  # S'
                else:
                    top = np.argsort(-w, kind="stable")[: params.k]
                    wt = w[top] / w[top].sum()
                    wifi = wt @ radio.rp_xy[rps[top]].astype(np.float64)  # S'
                vertex, inverse = np.unique(graph.rp_vertex[rps], return_inverse=True)
                p = np.bincount(inverse, weights=w)
                keep = np.argsort(-p, kind="stable")[: params.max_states]
                keep.sort()
                belief = mc.Belief(vertex[keep], p[keep] / p[keep].sum())
            else:
                wifi = None
        else:
            wifi = None
    else:
        wifi = np.array([found.x_m, found.y_m])

    if wifi is None:
        rejects = state.rejects + 1
        if rejects >= params.max_rejects:
            new = _start(state, m, maps, params)
            return new, _fix(new, event.t_ms, kind, {**diag, "reinitialised": 1.0})
        return replace(state, last_t_ms=event.t_ms, rejects=rejects), None

    z = blend(theta, wifi, inertial)  # Algorithm 3: S = (1 - θ) S' + θ S''
    u = update(x_pred, P_pred, z=z, H=scan_fixes.H_POSITION, R=m.var_m2 * np.eye(2))
    x_new = np.concatenate([u.x[:2], _at_most(u.x[2:], params.max_speed_mps)])
    new = replace(
        state,
        x=x_new,
        P=u.P,
        segment_scans=state.segment_scans + 1,
        last_t_ms=event.t_ms,
        kf_t_ms=event.t_ms,
        dr_xy=np.zeros(2),
        dr_m=0.0,
        steps_since=0,
        belief_vertex=belief.vertex if belief else state.belief_vertex,
        belief_p=belief.p if belief else state.belief_p,
        rejects=0,
    )
    return new, _fix(new, event.t_ms, kind, diag)


def _in_omega(
    maps: SiteMaps,
    m: scan_fixes.Matched,
    graph: FloorGraph,
    omega: NDArray[np.int64],
    params: MapMarkovParams,
) -> scan_fixes.Matched | None:
    """The scan matched among the map's reference scans whose nearest vertex is in Ω;
    None when Ω holds none."""
    assert maps.scans is not None
    on_floor = np.flatnonzero(maps.scans.floor == m.whole.floor)
    vertex = graph.tree.query(maps.scans.xy_m[on_floor])[1]
    near = np.zeros(len(maps.scans), dtype=bool)
    near[on_floor[np.isin(vertex, omega)]] = True
    used = scan_fixes.constrained(maps, m, params, near=near)
    return None if used is m else used


def _on_floor_change(
    state: MapMarkovState,
    change: FloorChange,
    maps: SiteMaps,
    params: MapMarkovParams,
    rng: np.random.Generator,
) -> tuple[MapMarkovState, Fix | None]:
    """The floor filter moves; the estimate itself moves with the next scan (the belief
    lives on one floor's graph)."""
    del params, rng
    logp, _ = scan_fixes.floor_moved(maps, state.floor_logp, state.floor, change)
    return replace(state, floor_logp=logp), None


# a batch in time order (stably): steps and scans as the module docstring says;
# magnetometer events and raw samples are ignored, deterministic
SPEC = EngineSpec(
    name="map_markov",
    params_type=MapMarkovParams,
    state_type=MapMarkovState,
    initial_state=initial_state,
    uses=phone_steps.USES,
    handlers=phone_steps.routes(on_step, on_scan, _on_floor_change),
    prepass=with_floor_changes,
)
