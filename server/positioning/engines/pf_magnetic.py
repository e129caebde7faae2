"""``pf_magnetic``: Shao et al.'s floor-plan constrained particle filter with the
mass-centered magnetic weight update (``papers/001_*`` sections II-IV).

* **Start** (section II): the first WiFi/BLE fix (WKNN, ``papers/002_*`` eq 1-3) seeds
  ``N`` particles uniformly on a disc of ``init_radius_m`` around it, on its floor, on
  walkable ground only (``server.positioning.filters.particle.initialise``).
* **Steps** (Algorithm 1, line 8): each step moves every particle by its length + δ along
  its heading + Δ; a particle whose move crosses a wall or ends outside walkable space is
  killed (``server.positioning.plan.floor_plan``). Steps come from the phone (``step`` events,
  heading clockwise from north) or from raw samples found by the server's PDR
  (``server.positioning.motion.step_tracker``: its north-referenced heading); the heading is
  turned into the building frame by the building's rotation (magnetic declination is not
  corrected). A step without a known north heading does not move the cloud.
* **Weights** (eq a-c): the magnetic field strength at the step (``mag`` events, or the
  raw magnetometer at the step's time) against each particle's map magnitudes over the
  last ``W + 1`` steps, with the mass-centered MMSE (``weighting="mass_centered"``) or the
  Magicol-style DTW baseline (``weighting="dtw"``); systematic resampling when the
  effective sample size falls below half of ``N``
  (``server.positioning.filters.particle.step``). Without a magnetic map the weights only come
  from the walls.
* **Floors**: the floor filter's floor after each scan (``scan_fixes.match``) takes
  the cloud there with the particles' positions kept (floors stack; particles on no
  walkable ground there die), as the EKF engines carry their position across a floor
  change. The paper does not change floors.
* **Radio weighting** (not in the paper, where WiFi/BLE only starts the cloud): each
  scan's fix weighs the particles by a Gaussian of the fix's learned variance mixed with
  a flat share (``radio_var_scale``, ``radio_outlier``).
* **Re-initialisation**: when the cloud dies (every particle killed), at the next scan;
  and when ``reinit_scans`` scans in a row place the phone farther than
  ``reinit_distance_m`` from the estimate (or on another floor, without
  ``follow_scan_floor``), around the latest scan.
* **Estimate**: the weighted mean of the particles, their covariance as its uncertainty,
  the floor with the most weight.

Randomness only through the ``rng`` the service passes per batch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Annotated, Literal, Self

import numpy as np
from annotated_types import Ge, Lt
from numpy.typing import NDArray

from server.positioning.engines.shared import scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import (
    EngineSpec,
    on,
    on_mag,
    on_scans,
    with_found_steps,
)
from server.positioning.filters import particle, particle_estimate
from server.positioning.filters import particle_cloud as pc
from server.positioning.filters.particle_resampling import alive, resample_when_low
from server.positioning.filters.particle_weight_update import reweight
from server.positioning.magnetic import field_grid
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import Event, Fix, MagEvent, StepEvent
from server.positioning.model.params import AtLeastOne, NonNegative, OpenShare, Positive
from server.positioning.motion.barometer import BaroState, FloorChange, initial_barometer
from server.positioning.motion.step_tracker import (
    Scan,
    Step,
    TrackerParams,
    TrackerState,
    initial_tracker,
)
from server.positioning.plan import floor_plan

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

MAG_MAX_AGE_MS = 1000  # a mag event this much older than a step does not belong to it


@dataclass(frozen=True)
class PfMagneticParams(scan_fixes.RadioParams):
    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.70, 1.60, 0.70, 5.20))
    particles: pc.ParticleParams = field(default_factory=pc.ParticleParams)
    tracker: TrackerParams = field(default_factory=TrackerParams)
    # or "dtw", the baseline of papers/001_* IV-B; "none" (an ablation) leaves the
    # magnetic field out: particles are weighted only by the walls
    weighting: Literal["mass_centered", "dtw", "none"] = "mass_centered"
    reinit_distance_m: Positive = 20.0
    reinit_scans: AtLeastOne = 3
    # not in Shao et al. (WiFi/BLE only starts the cloud there): every later scan also
    # weighs the particles by a Gaussian around its WKNN fix whose variance is the fix's
    # learned variance (fix_error) times ``radio_var_scale`` (0: no radio weighting), with
    # a share ``radio_outlier`` of the likelihood flat, so that one fix on the wrong side
    # of the building cannot empty the cloud
    radio_var_scale: NonNegative = 1.0
    radio_outlier: OpenShare = 0.05
    # a cloud that went astray recovers: at each scan whose floor the filter is sure of
    # (floor_prob >= 0.9), this share of the particles is drawn again around the fix (a
    # Gaussian of its variance, on walkable ground), each at the cloud's mean weight;
    # inner validation, P75 with / without: ILC site2 18.6 / 19.5 m, IPIN 18.1 / 18.5 m
    recover_share: Annotated[float, Ge(0), Lt(1)] = 0.02
    # move the cloud to the floor each scan votes for, keeping the particles' positions
    # (as the EKF engines do), rather than waiting for reinit_scans disagreeing scans: on
    # the inner validation split of ILC site2 the mean error fell from 51.1 m to 33.3 m
    # and the floor hit rate rose from 71.8 % to 80.4 %
    follow_scan_floor: bool = True


@dataclass(frozen=True)
class PfMagneticState:
    tracker: TrackerState
    cloud: pc.Particles | None  # None before the first fix and after the cloud died
    disagree: int  # scans in a row that put the phone far from the estimate
    mag_t_ms: float  # time of the last mag event (NaN: none)
    mag_ut: float  # its field strength
    heading_rad: float  # map-frame heading of the last step (NaN: none)
    # the floor filter after its last scan (empty: none yet)
    floor_logp: FloatArray = field(default_factory=lambda: scan_fixes.EMPTY)
    floor_t_ms: int = 0  # time of that scan
    baro: BaroState = field(default_factory=initial_barometer)  # floor changes by pressure

    def with_field(self, t_ms: int, strength_ut: float) -> Self:
        """A magnetometer reading: the latest, for the phone's next step."""
        return replace(self, mag_t_ms=float(t_ms), mag_ut=float(strength_ut or math.nan))


def initial_state(params: PfMagneticParams) -> PfMagneticState:
    return PfMagneticState(
        tracker=initial_tracker(params.tracker),
        cloud=None,
        disagree=0,
        mag_t_ms=math.nan,
        mag_ut=math.nan,
        heading_rad=math.nan,
    )


# ---------------------------------------------------------------- the maps as callables


def _one_floor(floors: NDArray[np.int16]) -> int | None:
    """The floor of every particle when they share one (the usual case: a scan moves the
    whole cloud), else None."""
    if floors.shape[0] and bool((floors == floors[0]).all()):
        return int(floors[0])
    return None


def _valid_move(maps: SiteMaps) -> pc.MoveCheck:
    def plan_of(f: int) -> floor_plan.FloorPlan | None:
        return maps.plans[f] if 0 <= f < len(maps.plans) else None

    def check(floors: NDArray[np.int16], a: FloatArray, b: FloatArray) -> BoolArray:
        ok: BoolArray = np.isfinite(b[:, 0]) & np.isfinite(b[:, 1])
        one = _one_floor(floors)
        if one is not None:
            plan = plan_of(one)
            # valid_moves is False for a non-finite b
            return ok if plan is None else floor_plan.valid_moves(plan, a, b)
        for f in np.unique(floors):
            plan = plan_of(int(f))
            if plan is not None:
                rows = np.flatnonzero(floors == f)
                ok[rows] &= floor_plan.valid_moves(plan, a[rows], b[rows])
        return ok

    return check


def _valid_point(maps: SiteMaps) -> pc.PointCheck:
    def plan_of(f: int) -> floor_plan.FloorPlan | None:
        return maps.plans[f] if 0 <= f < len(maps.plans) else None

    def check(floors: NDArray[np.int16], xy: FloatArray) -> BoolArray:
        one = _one_floor(floors)
        if one is not None and (plan := plan_of(one)) is not None:
            # walkable_at is False for a non-finite point
            return floor_plan.walkable_at(plan, xy)
        ok: BoolArray = np.asarray(np.isfinite(xy).all(axis=1), dtype=bool)
        for f in np.unique(floors):
            plan = plan_of(int(f))
            if plan is not None:
                rows = floors == f
                ok[rows] &= floor_plan.walkable_at(plan, xy[rows])
        return ok

    return check


def _sample_map(maps: SiteMaps) -> pc.MapSampler:
    grids = maps.magnetic.grids if maps.magnetic is not None else ()

    def grid_of(f: int) -> field_grid.MagneticGrid | None:
        return grids[f] if 0 <= f < len(grids) else None

    def sample(floors: NDArray[np.int16], xy: FloatArray) -> FloatArray:
        out = np.full(len(xy), np.nan)
        one = _one_floor(floors)
        if one is not None:
            grid = grid_of(one)
            return out if grid is None else field_grid.sample(grid, xy)
        for f in np.unique(floors):
            grid = grid_of(int(f))
            if grid is not None:
                rows = np.flatnonzero(floors == f)
                out[rows] = field_grid.sample(grid, xy[rows])
        return out

    return sample


# ---------------------------------------------------------------- events


def _fix(
    cloud: pc.Particles, t_ms: int, heading: float, source: str, diag: dict[str, float]
) -> Fix:
    est = particle_estimate.estimate(cloud)
    c = est.cov
    # the scan's floor filter where a scan made the fix, else the weight on the floor
    diag = {"floor_prob": est.floor_prob, **diag, "ess": est.ess}
    return Fix(
        t_ms=t_ms,
        x_m=float(est.xy[0]),
        y_m=float(est.xy[1]),
        floor=est.floor,
        heading_rad=heading if math.isfinite(heading) else None,
        cov=(float(c[0, 0]), float(c[0, 1]), float(c[1, 0]), float(c[1, 1])),
        source=source,
        diagnostics=diag,
    )


def _on_step(
    state: PfMagneticState,
    step: Step,
    maps: SiteMaps,
    params: PfMagneticParams,
    rng: np.random.Generator,
) -> tuple[PfMagneticState, Fix | None]:
    t_ms, length_m, north_rad, magnitude_ut = (
        step.t_ms,
        step.length_m,
        step.north_rad,
        step.magnitude_ut,
    )
    cloud = state.cloud
    if cloud is None or not math.isfinite(north_rad) or not math.isfinite(length_m):
        return state, None
    one = _one_floor(cloud.floor)
    floor = particle_estimate.position(cloud)[1] if one is None else one
    heading = scan_fixes.in_building_frame(maps, floor, north_rad)
    use_field = math.isfinite(magnitude_ut) and params.weighting != "none"
    observed = magnitude_ut if use_field else None
    if one is not None and params.weighting != "dtw":
        # the usual case, in one compiled pass: the same answer as particle.step
        grids = maps.magnetic.grids if maps.magnetic is not None else ()
        moved = particle.step_on_floor(
            cloud,
            length_m,
            heading,
            observed,
            rng,
            params.particles,
            maps.plans[one] if 0 <= one < len(maps.plans) else None,
            grids[one] if 0 <= one < len(grids) else None,
        )
    else:
        moved = particle.step(
            cloud,
            length_m,
            heading,
            observed,
            rng,
            params.particles,
            _valid_move(maps),
            _sample_map(maps),
            weighting="dtw" if params.weighting == "dtw" else "mass_centered",
        )
    if not alive(moved):
        return replace(state, cloud=None, heading_rad=heading), None
    new = replace(state, cloud=moved, heading_rad=heading)
    return new, _fix(moved, t_ms, heading, "step", {"step_length_m": length_m})


def _on_scan(
    state: PfMagneticState,
    event: Scan,
    maps: SiteMaps,
    params: PfMagneticParams,
    rng: np.random.Generator,
) -> tuple[PfMagneticState, Fix | None]:
    m = scan_fixes.match(maps, event, params, state.floor_logp, state.floor_t_ms, state.baro)
    if m is None:
        return state, None
    kind, found = m.kind, m.whole
    diag = {
        "n_matched": float(m.n_matched),
        "fix_var_m2": m.var_m2,
        "floor_prob": found.floor_prob,
    }
    # the state is replaced once, at the end, with the floor filter after this scan
    cloud = state.cloud
    if cloud is not None and params.follow_scan_floor:
        cloud = _to_floor(cloud, found.floor, maps)
        cloud = cloud if alive(cloud) else None
    if cloud is not None:
        xy, floor = particle_estimate.position(cloud)
        far = math.hypot(xy[0] - found.x_m, xy[1] - found.y_m) > params.reinit_distance_m
        disagree = state.disagree + 1 if far or floor != found.floor else 0
        if disagree < params.reinit_scans:
            if params.radio_var_scale > 0:
                cloud = _radio_weights(cloud, m, params, rng)
            if params.recover_share > 0 and found.floor_prob >= 0.9 and alive(cloud):
                cloud = _recover(cloud, m, params.recover_share, maps, rng)
            new = replace(
                state, floor_logp=m.floor_logp, floor_t_ms=m.t_ms, disagree=disagree, cloud=cloud
            )
            return new, _fix(cloud, event.t_ms, state.heading_rad, kind, diag)
        diag["reinitialised"] = 1.0
    cloud = particle.initialise(
        (found.x_m, found.y_m),
        found.floor,
        rng,
        params.particles,
        valid_point=_valid_point(maps),
    )
    new = replace(state, floor_logp=m.floor_logp, floor_t_ms=m.t_ms, cloud=cloud, disagree=0)
    return new, _fix(cloud, event.t_ms, state.heading_rad, kind, diag)


def _to_floor(cloud: pc.Particles, floor: int, maps: SiteMaps) -> pc.Particles:
    """Every particle onto ``floor`` at its position; those not on walkable ground there die."""
    if bool((cloud.floor == floor).all()):
        return cloud
    floors = np.full(cloud.n, floor, dtype=np.int16)
    ok = _valid_point(maps)(floors, cloud.xy.astype(np.float64))
    moved = replace(cloud, floor=floors)
    return reweight(moved, np.where(ok, 0.0, -np.inf))


def _radio_weights(
    cloud: pc.Particles,
    m: scan_fixes.Matched,
    params: PfMagneticParams,
    rng: np.random.Generator,
) -> pc.Particles:
    """Particles weighed by the scan's fix: a Gaussian of the fix's variance (scaled by
    ``radio_var_scale``) mixed with a flat share ``radio_outlier``; a particle on another
    floor than the fix's (the cloud is moved there unless ``follow_scan_floor`` is off)
    gets the flat share once more."""
    var = m.var_m2 * params.radio_var_scale
    # the squared distances to the fix, column by column and in place: the same numbers
    # as over the (n, 2) rows, several times faster
    d2 = np.subtract(cloud.xy[:, 0], m.whole.x_m, dtype=np.float64)
    d2 *= d2
    dy = np.subtract(cloud.xy[:, 1], m.whole.y_m, dtype=np.float64)
    dy *= dy
    d2 += dy
    d2 *= -0.5
    d2 /= var
    d2 += math.log1p(-params.radio_outlier)
    ll = np.logaddexp(d2, math.log(params.radio_outlier))
    if _one_floor(cloud.floor) != m.whole.floor:
        # particles on another floor than the fix's (only without follow_scan_floor)
        ll = np.where(cloud.floor == m.whole.floor, ll, ll + math.log(params.radio_outlier))
    cloud = reweight(cloud, ll)
    if not alive(cloud):
        return cloud
    return resample_when_low(cloud, rng, params.particles)


def _recover(
    cloud: pc.Particles,
    m: scan_fixes.Matched,
    share: float,
    maps: SiteMaps,
    rng: np.random.Generator,
) -> pc.Particles:
    """A share of the particles, picked at random, drawn again around the fix (see
    ``PfMagneticParams.recover_share``); draws off walkable ground keep their particle."""
    n_new = round(share * cloud.n)
    if n_new == 0:
        return cloud
    pick = rng.choice(cloud.n, n_new, replace=False)
    xy = np.array([m.whole.x_m, m.whole.y_m]) + rng.normal(0.0, math.sqrt(m.var_m2), (n_new, 2))
    floors = np.full(n_new, m.whole.floor, dtype=np.int16)
    ok = _valid_point(maps)(floors, xy)
    pick, xy = pick[ok], xy[ok]
    if pick.size == 0:
        return cloud
    new_xy = cloud.xy.copy()
    new_xy[pick] = xy.astype(np.float32)
    new_floor = cloud.floor.copy()
    new_floor[pick] = m.whole.floor
    mags = cloud.mags.copy()
    mags[pick] = np.nan  # no field history at the new places
    log_w = cloud.log_w.astype(np.float64)
    finite = np.isfinite(log_w)
    live = log_w if finite.all() else log_w[finite]
    log_w[pick] = float(np.log(np.mean(np.exp(live)))) if live.size else 0.0
    # the arrays are the cloud's own, copied and changed in place: no checks needed
    moved = pc.unchecked(
        cloud, xy=new_xy, floor=new_floor, mags=mags, log_w=np.zeros(cloud.n, np.float32)
    )
    return reweight(moved, log_w)


def _on_phone_step(
    state: PfMagneticState,
    event: StepEvent,
    maps: SiteMaps,
    params: PfMagneticParams,
    rng: np.random.Generator,
) -> tuple[PfMagneticState, Fix | None]:
    """A step the phone detected, with the latest mag event if it is recent."""
    recent = math.isfinite(state.mag_t_ms) and 0 <= event.t_ms - state.mag_t_ms <= MAG_MAX_AGE_MS
    step = Step(
        event.t_ms,
        event.length_m,
        event.heading_rad,
        event.heading_rad,
        True,
        state.mag_ut if recent else math.nan,
    )
    return _on_step(state, step, maps, params, rng)


def _prepass(
    state: PfMagneticState, events: Sequence[Event], maps: SiteMaps, params: PfMagneticParams
) -> tuple[PfMagneticState, list[Step | Scan | StepEvent | MagEvent | FloorChange]]:
    """Raw IMU blocks become steps, the barometer's floor changes join them
    (``with_found_steps``); phone steps and mag events are taken as they come."""
    state, items = with_found_steps(state, events, maps, params)
    return state, [*items, *(e for e in events if isinstance(e, StepEvent | MagEvent))]


def _on_floor_change(
    state: PfMagneticState,
    change: FloorChange,
    maps: SiteMaps,
    params: PfMagneticParams,
    rng: np.random.Generator,
) -> tuple[PfMagneticState, Fix | None]:
    """The floor filter shifted by a barometric floor change and the cloud moved onto its
    most likely floor (particles off that floor's walkable space die)."""
    del params, rng
    if state.cloud is not None:
        floor = particle_estimate.position(state.cloud)[1]
    else:  # the cloud died: the next scan starts it again, on the shifted filter's floor
        floor = int(np.argmax(state.floor_logp)) if state.floor_logp.size else -1
    logp, floor = scan_fixes.floor_moved(maps, state.floor_logp, floor, change)
    state = replace(state, floor_logp=logp)
    if state.cloud is None:
        return state, None
    moved = _to_floor(state.cloud, floor, maps)
    return replace(state, cloud=moved if alive(moved) else None), None


def _rank(item: Step | Scan | StepEvent | MagEvent | FloorChange) -> int:
    """At equal times: the field first, then the step it belongs to, then the scan (and
    the floor change)."""
    if isinstance(item, MagEvent):
        return 0
    return 1 if isinstance(item, Step | StepEvent) else 2


# a batch in time order: raw IMU blocks become steps; phone steps, mag events and scans are
# taken as they come
SPEC = EngineSpec(
    name="pf_magnetic",
    params_type=PfMagneticParams,
    state_type=PfMagneticState,
    initial_state=initial_state,
    uses=frozenset({"imu", "step", "mag", "wifi", "ble", "pressure"}),
    handlers=(
        on(MagEvent, on_mag),
        on(StepEvent, _on_phone_step),
        on(Step, _on_step),
        *on_scans(_on_scan),
        on(FloorChange, _on_floor_change),
    ),
    prepass=_prepass,
    rank=_rank,
)
