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

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines.shared import scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, on, on_scans, with_floor_changes
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Fix, WifiEvent
from server.positioning.motion.barometer import BaroState, FloorChange, initial_barometer


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


def on_scan(
    state: WknnState,
    event: WifiEvent | BleEvent,
    maps: SiteMaps,
    params: WknnParams,
    rng: np.random.Generator,
) -> tuple[WknnState, Fix | None]:
    """Locate one scan on its own: a fix when it matched the map (``maps.radio``, by
    WKNN; without it no fix), the floor filter after it."""
    del rng  # matching is deterministic
    state, m = scan_fixes.scan_matched(state, event, maps, params)
    if m is None:
        return state, None
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
    new = replace(state, floor=found.floor, n_fixes=state.n_fixes + 1, last_t_ms=event.t_ms)
    return new, fix


# a batch in time order (stably): one fix per WiFi or BLE scan that matched the map; step
# and magnetometer events are ignored
SPEC = EngineSpec(
    name="wknn",
    params_type=WknnParams,
    state_type=WknnState,
    initial_state=initial_state,
    uses=frozenset({"wifi", "ble", "pressure"}),
    handlers=(
        *on_scans(on_scan),
        on(FloorChange, scan_fixes.on_floor_change),
    ),
    prepass=with_floor_changes,
)
