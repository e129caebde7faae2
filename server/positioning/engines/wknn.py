"""``wknn``: one fix per radio scan by weighted K-nearest neighbours, no motion model.

The baseline every fusion engine has to beat. Each WiFi scan (and each BLE scan, when the
map has BLE columns) that heard at least ``min_matched`` map emitters is matched on its
own against the radio map (``server.positioning.radio.fingerprints.wknn``, ``papers/002_*``
section 4.1):

* signal distance to each reference point, ``papers/002_*`` eq 1;
* floor by the floor filter (``floor_hmm``): the scan's likelihood of each floor
  times the filter's prediction, so the floor has a memory even without motion;
* position as the 1/D-weighted mean of the K nearest reference points of that floor
  (every RP tied with the K-th taking part), ``papers/002_*`` eq 3.

The fix's covariance is ``var * I`` with ``var`` what a fix of its kind and matched
emitters is worth on this map (``SiteMaps.fix_error``; ``scan_fixes.match``). The
WKNN spread of ``papers/003_*`` eq 17 is reported as ``wknn_var_m2`` only. Steps and
magnetometer events are ignored, so fixes carry no heading.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines import driver
from server.positioning.engines.spec import EngineSpec
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Event, Fix, WifiEvent
from server.positioning.model.site_maps import SiteMaps
from server.positioning.motion.barometer import BaroState, FloorChange, initial_barometer
from server.positioning.radio import scan_fixes


@dataclass(frozen=True)
class WknnParams(scan_fixes.RadioParams):
    """Parameters of the ``wknn`` engine: those every scan-matching engine shares."""

    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.90, 0.50, 0.90, 2.30))


@dataclass(frozen=True)
class WknnState:
    """State of one ``wknn`` session: nothing the next fix depends on, only bookkeeping.

    Attributes
    ----------
    floor : int
        Floor index of the last fix; -1 before any.
    n_fixes : int
        Fixes produced so far.
    last_t_ms : int
        Time of the last scan processed (0 before any).
    """

    floor: int = -1
    n_fixes: int = 0
    last_t_ms: int = 0
    floor_logp: NDArray[np.float64] = field(
        default_factory=lambda: scan_fixes.EMPTY
    )  # floor filter
    floor_t_ms: int = 0  # time of that scan
    baro: BaroState = field(default_factory=initial_barometer)  # floor changes by pressure


def initial_state(params: WknnParams) -> WknnState:
    """A state before any fix."""
    del params  # the state does not depend on them
    return WknnState()


def _locate(
    event: WifiEvent | BleEvent, state: WknnState, maps: SiteMaps, params: WknnParams
) -> tuple[WknnState, Fix | None]:
    m = scan_fixes.match(maps, event, params, state.floor_logp, state.floor_t_ms, state.baro)
    if m is None:
        return replace(state, last_t_ms=event.t_ms), None
    found = m.whole
    fix = Fix(
        t_ms=event.t_ms,
        x_m=found.x_m,
        y_m=found.y_m,
        floor=found.floor,
        heading_rad=None,
        cov=(m.var_m2, 0.0, 0.0, m.var_m2),
        source=m.kind,
        diagnostics={
            "n_matched": float(m.n_matched),
            "wknn_var_m2": found.var_m2,
            "floor_prob": found.floor_prob,
        },
    )
    new = replace(
        state,
        floor=found.floor,
        n_fixes=state.n_fixes + 1,
        last_t_ms=event.t_ms,
        floor_logp=m.floor_logp,
        floor_t_ms=event.t_ms,
    )
    return new, fix


def run(
    state: WknnState,
    events: Sequence[Event],
    maps: SiteMaps,
    params: WknnParams,
    rng: np.random.Generator,
) -> tuple[WknnState, list[Fix]]:
    """Locate every scan of a batch on its own.

    Parameters
    ----------
    state : WknnState
        State after the previous batch (``initial_state`` for a new session).
    events : sequence of Event
        Sorted by ``t_ms`` here (stably). Step and magnetometer events are ignored.
    maps : SiteMaps
        ``maps.radio`` is matched by WKNN; without it no fix is produced.
    params : WknnParams
    rng : numpy.random.Generator
        Unused: matching is deterministic.

    Returns
    -------
    state : WknnState
    fixes : list of Fix
        One per WiFi or BLE scan that matched the map, in time order.
    """
    del rng  # engines share one signature; this one draws no random numbers

    def locate(st: WknnState, event: WifiEvent | BleEvent) -> tuple[WknnState, Fix | None]:
        return _locate(event, st, maps, params)

    routes = [
        driver.on(WifiEvent, locate),
        driver.on(BleEvent, locate),
        driver.on(FloorChange, scan_fixes.moved_by(maps)),
    ]
    return scan_fixes.walk_with_floor_changes(state, events, maps, params, routes)


SPEC = EngineSpec(
    name="wknn",
    params_type=WknnParams,
    state_type=WknnState,
    initial_state=initial_state,
    run=run,
    uses=frozenset({"wifi", "ble", "pressure"}),
)
