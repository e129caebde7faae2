"""The WiFi/BLE side shared by every engine that matches scans.

Per scan (``match``):

1. the scan is matched against the map's own surveyed scans (``scan_matching``: the
   shared-emitter distance with reading ages and rare-emitter weights) if it heard at
   least ``min_matched`` map emitters (one or two beacons tie with hundreds of
   references); a map built without its scans is matched on its cells instead (WKNN,
   ``papers/002_*`` eq 1-3). The floor is chosen by the floor filter (``floor_hmm``:
   the filter's prediction times the scan's likelihood of each floor), not by the scan
   alone: on ILC site2 the per-scan vote had an 85 % floor hit rate and every engine
   inherited it. Engines that search near their estimate (a moving partition, a
   motion-aided selection) match the scan again among the references they keep
   (``constrained``);
2. the fix's variance is what the map's training data say a fix of this kind with this
   many matched emitters is worth (``SiteMaps.fix_error``, learned by
   ``mapping.fix_calibration``), times ``fix_var_scale``, times (the nearest reference
   scan's distance / ``fix_var_match_db``) ** ``fix_var_match_power`` where the scan was
   matched against the map's scans, at least ``min_fix_var_m2``.

Between scans, the barometer (``barometer``, from the pressure rows of the batch's raw
sample blocks) reports settled floor changes; ``floor_changes`` finds them (an engine's
pre-pass adds them to its batch, ``spec``) and ``floor_moved`` shifts the floor
filter by them (``floor_hmm.shift``; ``on_floor_change`` is the handler of an engine
whose state has a floor and the filter), so a walk up the stairs moves the floor when
the pressure settles, not when the sticky filter has heard enough scans of the new floor.

What the Kalman filter engines then do with the fix is in ``pdr_kalman``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Annotated, Protocol, TypeVar

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.filters.kalman import Update, update, wrap_angle, wrap_angle_float
from server.positioning.model.accuracy import EngineParams
from server.positioning.model.events import Event, Fix, ImuEvent, WifiEvent
from server.positioning.model.params import AtLeastOne, NonNegative, Positive
from server.positioning.motion import barometer
from server.positioning.motion.barometer import BaroParams, BaroState, FloorChange
from server.positioning.motion.step_tracker import Scan
from server.positioning.radio import floor_hmm, scan_matching
from server.positioning.radio.fingerprints import ScanVector, WknnFix, scan_vector, wknn
from server.positioning.radio.scan_matching import MatchParams

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

H_POSITION = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]])


EMPTY = np.zeros(0)


@dataclass(frozen=True)
class RadioParams(EngineParams):
    """What every engine that matches scans shares: WKNN, the evidence a fix needs, the
    floor filter (``floor_hmm``) and the floor under the fix variance."""

    k: Annotated[int, Ge(1), Le(100)] = 4  # WKNN neighbours K, papers/002_* eq 3
    # scans that match fewer map emitters give no fix: one or two beacons tie with
    # hundreds of reference points all over the building
    min_matched: AtLeastOne = 3
    floor_sd_db: Positive = 8.0  # RSS error per emitter in the floor likelihood (fingerprint)
    floor_max_emitters: AtLeastOne = 10  # matched emitters counted as independent votes, at most
    # floor filter: floor changes per second. 0.001 against 0.01: the IPIN validation
    # floor hit 77 -> 85 %, site2's unchanged (bench/accuracy.md)
    floor_change_per_s: NonNegative = 0.001
    # the same while the barometer is live (barometer.live): it reports the floor
    # changes itself (floor_changes). 1e-4 against 0.001: IPIN validation floor hit
    # 84.5 -> 88.5 %, score 15.8 -> 12.3 m; 1e-5 and 0 the same as 1e-4 (bench/accuracy.md)
    floor_change_per_s_baro: NonNegative = 1e-4
    # floor under the learned fix variance (fix_error): a fix is never trusted to 2 m
    min_fix_var_m2: Positive = 4.0
    # the learned variance is that of one fix on its own; a filter that takes fix after
    # fix along a walk meets errors shared by neighbouring scans (the same wrong
    # reference points), so it uses the variance times this factor
    fix_var_scale: Positive = 1.0
    # a scan matched against the map's scans: the learned variance times (the nearest
    # reference's distance / fix_var_match_db) ** fix_var_match_power, as a fix far from
    # every reference scan is worth less than one beside one. Power 1 at 10 dB against
    # none: validation step_ekf site2 10.26 -> 9.95 m, IPIN 12.16 -> 11.29 m, score
    # 12.28 -> 11.70 m (5 dB, 20 dB, power 0.5, 1.5, 2 in bench/accuracy.md)
    fix_var_match_db: Positive = 10.0
    fix_var_match_power: NonNegative = 1.0
    # matching against the map's own scans (scan_matching), where the map has them
    scan_k: Annotated[int, Ge(1), Le(100)] = MatchParams.k
    match_power: Positive = MatchParams.power
    shared_penalty_db: NonNegative = MatchParams.penalty_db
    scan_same_floor: bool = MatchParams.same_floor
    scan_floor_k: Annotated[int, Ge(1), Le(100)] = MatchParams.floor_k
    scan_floor_sd_db: Positive = MatchParams.floor_sd_db
    scan_floor_max_emitters: AtLeastOne = MatchParams.floor_max_emitters
    barometer: BaroParams = field(default_factory=BaroParams)

    def matching(self) -> MatchParams:
        """What ``scan_matching`` reads of these parameters."""
        return MatchParams(
            k=self.scan_k,
            power=self.match_power,
            penalty_db=self.shared_penalty_db,
            same_floor=self.scan_same_floor,
            floor_k=self.scan_floor_k,
            floor_sd_db=self.scan_floor_sd_db,
            floor_max_emitters=self.scan_floor_max_emitters,
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
    query: scan_matching.Query | None = None  # the scan over the map's scans, if it has them

    @property
    def n_matched(self) -> int:
        """Emitters of the scan the map matched it on."""
        return self.whole.n_matched

    @property
    def floor_logp(self) -> FloatArray:
        """The floor filter after this scan."""
        return self.whole.floor_logp


def scan_kind(event: Scan) -> str:
    return "wifi" if isinstance(event, WifiEvent) else "ble"


def match(
    maps: SiteMaps,
    event: Scan,
    params: RadioParams,
    floor_logp: FloatArray = EMPTY,
    floor_t_ms: int = 0,
    baro: BaroState | None = None,
) -> Matched | None:
    """Match a scan on the whole map, the floor filtered from ``floor_logp`` (the floor
    filter after its last scan at ``floor_t_ms``; empty: nothing known; predicted at
    ``floor_change_per_s_baro`` while ``baro`` is live). None when there is no map, the
    scan matched fewer than ``min_matched`` map columns or no reference point shares an
    emitter with it."""
    if maps.radio is None:
        return None
    kind = scan_kind(event)
    scan = scan_vector(maps.radio, event.readings, kind)
    rate = params.floor_change_per_s
    if baro is not None and barometer.live(baro, event.t_ms, params.barometer):
        rate = params.floor_change_per_s_baro
    prior = floor_hmm.prior(floor_logp, floor_t_ms, event.t_ms, rate)
    whole: WknnFix | None
    q = None
    if maps.scans is not None:
        q = scan_matching.query(maps.scans, event.readings, kind)
        if q.n_matched < params.min_matched:
            return None
        whole = scan_matching.locate(
            maps.scans,
            q,
            params.matching(),
            prior,
            n_floors=len(maps.floors),
            floor_group=floor_groups(maps.floors)[1] if maps.floors else None,
        )
    else:
        whole = wknn(
            maps.radio,
            scan,
            k=params.k,
            floor_log_prior=prior,
            floor_sd_db=params.floor_sd_db,
            floor_max_emitters=params.floor_max_emitters,
            min_matched=params.min_matched,
        )
    if whole is None:
        return None
    learned = maps.fix_error.variance(kind, whole.n_matched)
    if q is not None and whole.distances_db.size:
        nearest = max(float(whole.distances_db.min()), 0.1)
        learned *= (nearest / params.fix_var_match_db) ** params.fix_var_match_power
    var = max(learned * params.fix_var_scale, params.min_fix_var_m2)
    return Matched(event.t_ms, kind, scan, whole, var, q)


class Scanning(Protocol):
    """An engine state with the floor filter, the barometer and the time of the last
    event it took."""

    @property
    def floor_logp(self) -> FloatArray: ...
    @property
    def floor_t_ms(self) -> int: ...
    @property
    def baro(self) -> BaroState: ...
    @property
    def last_t_ms(self) -> int: ...


L = TypeVar("L", bound=Scanning)


def scan_matched(
    state: L, event: Scan, maps: SiteMaps, params: RadioParams
) -> tuple[L, Matched | None]:
    """The scan matched on the whole map with the state's floor filter and barometer
    (``match``), and the state with the floor filter after it; when it matched nothing,
    None and the state only at the scan's time (``last_t_ms``)."""
    m = match(maps, event, params, state.floor_logp, state.floor_t_ms, state.baro)
    if m is None:
        unmatched: L = replace(state, last_t_ms=event.t_ms)  # type: ignore[type-var]
        return unmatched, None
    new: L = replace(state, floor_logp=m.floor_logp, floor_t_ms=m.t_ms)  # type: ignore[type-var]
    return new, m


class BarometerParams(Protocol):
    """What ``floor_changes`` reads of an engine's parameters (``RadioParams`` has it)."""

    @property
    def barometer(self) -> BaroParams: ...


def floor_changes(
    baro: BaroState, events: Sequence[Event], maps: SiteMaps, params: BarometerParams
) -> tuple[BaroState, list[FloorChange]]:
    """The barometer advanced over the pressure rows of the batch's raw sample blocks (in
    time order), and the floor changes it settled on (an engine's pre-pass:
    ``spec.with_floor_changes``)."""
    spacing = maps.floor_spacing_hpa or barometer.DEFAULT_SPACING_HPA
    changes: list[FloorChange] = []
    blocks = sorted((e for e in events if isinstance(e, ImuEvent)), key=lambda e: e.t_ms)
    for imu in blocks:
        if imu.pressure.shape[0]:
            baro, found = barometer.advance(baro, imu.pressure, spacing, params.barometer)
            changes += found
    return baro, changes


class Floored(Protocol):
    """An engine state with a floor estimate and the floor filter."""

    @property
    def floor(self) -> int: ...
    @property
    def floor_logp(self) -> FloatArray: ...


S = TypeVar("S", bound=Floored)


def on_floor_change(
    state: S,
    change: FloorChange,
    maps: SiteMaps,
    params: EngineParams,
    rng: np.random.Generator,
) -> tuple[S, Fix | None]:
    """The handler of a barometric floor change for an engine state whose ``floor`` and
    ``floor_logp`` say the floor (``floor_moved``); it makes no fix."""
    del params, rng  # the same move for every engine
    logp, floor = floor_moved(maps, state.floor_logp, state.floor, change)
    new: S = replace(state, floor_logp=logp, floor=floor)  # type: ignore[type-var]
    return new, None


def floor_moved(
    maps: SiteMaps, floor_logp: FloatArray, floor: int, change: FloorChange
) -> tuple[FloatArray, int]:
    """The floor filter after a barometric floor change, and the estimate's floor index
    after it (its most likely floor; ``floor`` unchanged while that is -1, not yet
    known, or the filter knows nothing yet)."""
    if floor_logp.shape[0] == 0 or floor < 0:
        return floor_logp, floor
    levels, buildings = floor_groups(maps.floors)
    moved = floor_hmm.shift(floor_logp, change.floors, levels, buildings)
    return moved, int(np.argmax(moved))


@functools.lru_cache(maxsize=64)
def floor_groups(floors: tuple[FloorRef, ...]) -> tuple[IntArray, IntArray]:
    """Each floor's level and its building's index (in sorted building id order), once
    per site's floors rather than per scan."""
    levels = np.array([f.level for f in floors], dtype=np.int64)
    buildings = np.unique([f.building_id for f in floors], return_inverse=True)[1]
    return levels, buildings.astype(np.int64).reshape(-1)


def reference_xy(maps: SiteMaps) -> FloatArray:
    """Where the map's references were taken: its scans where it has them, else its
    cells' reference points (what ``constrained`` masks and penalises)."""
    if maps.scans is not None:
        return maps.scans.xy_m
    assert maps.radio is not None
    return maps.radio.rp_xy.astype(np.float64)


def constrained(
    maps: SiteMaps,
    m: Matched,
    params: RadioParams,
    near: NDArray[np.bool_] | None = None,
    penalty_db: FloatArray | None = None,
) -> Matched:
    """The scan matched again among the references of its floor that ``near`` keeps (a
    mask over ``reference_xy``), with ``penalty_db`` added to their distances: a moving
    partition, a motion-aided selection. The match as it was when none is left."""
    if maps.scans is not None:
        if m.query is None:  # not matched on these scans: nothing to match again
            return m
        on_floor = maps.scans.floor == m.whole.floor
        keep = on_floor if near is None else on_floor & near
        found = scan_matching.locate(
            maps.scans,
            m.query,
            replace(params.matching(), same_floor=True),
            candidates=keep,
            penalty_db=penalty_db,
            n_floors=len(maps.floors),
        )
    else:
        assert maps.radio is not None
        on_floor = maps.radio.rp_floor == m.whole.floor
        found = wknn(
            maps.radio,
            m.scan,
            k=params.k,
            candidates=on_floor if near is None else on_floor & near,
            penalty_db=penalty_db,
        )
    return refined(m, found)


def on_cells(maps: SiteMaps, m: Matched, params: RadioParams) -> WknnFix | None:
    """WKNN of the scan over the radio map's cells of the matched floor: for what reads
    the cells' reference points (the FAI indicators, the map graphs' vertices)."""
    if maps.radio is None:
        return None
    if maps.scans is None:
        return m.whole
    found = wknn(
        maps.radio,
        m.scan,
        k=params.k,
        candidates=maps.radio.rp_floor == m.whole.floor,
        min_matched=1,
    )
    return None if found is None else replace(found, floor=m.whole.floor)


def refined(m: Matched, found: WknnFix | None) -> Matched:
    """The match with another fix of the same scan (a partition's, an aided one's), on
    the floor the whole-map match chose; the whole-map fix when there is none."""
    if found is None:
        return m
    return replace(m, whole=replace(found, floor=m.whole.floor, floor_logp=m.whole.floor_logp))


def position_update(x: FloatArray, P: FloatArray, m: Matched) -> Update:
    return update(x, P, z=[m.whole.x_m, m.whole.y_m], H=H_POSITION, R=m.var_m2 * np.eye(2))


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


def in_building_frame(maps: SiteMaps, floor: int, north_rad: float) -> float:
    """A heading clockwise from north turned into the frame of the floor's building."""
    rotation = maps.floors[floor].rotation_rad if 0 <= floor < len(maps.floors) else 0.0
    return wrap_angle_float(north_rad - rotation)


def turn_between(previous_rad: float, heading_rad: float) -> float:
    """The wrapped change of the phone heading since the previous step (0 when either is
    unknown)."""
    if math.isfinite(heading_rad) and math.isfinite(previous_rad):
        return float(wrap_angle(heading_rad - previous_rad))
    return 0.0
