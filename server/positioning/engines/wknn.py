"""``wknn``: one fix per radio scan by weighted K-nearest neighbours, no motion model.

The baseline every fusion engine has to beat. Each WiFi scan (and each BLE scan, when the
map has BLE columns and the scan hears one of them) is matched on its own against the
radio map (``server.positioning.fingerprint.wknn``, ``papers/002_*`` section 4.1):

* signal distance to each reference point, ``papers/002_*`` eq 1;
* floor by the 1/D-weighted vote of the K nearest reference points over all floors;
* position as the 1/D-weighted mean of the K nearest reference points of that floor,
  ``papers/002_*`` eq 3.

The fix's covariance is ``var * I`` with ``var = max(var_FP, min_fix_var_m2)``, where
``var_FP`` is the WKNN spread of ``papers/003_*`` eq 17; that spread is not a calibrated
variance (see ``fingerprint``), hence the same floor under it as in ``step_ekf``. Steps and
magnetometer events are ignored, so fixes carry no heading. A scan that matches nothing
(no map, or no map column heard) gives no fix.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from server.positioning.engines.base import EngineSpec, SiteMaps
from server.positioning.events import BleEvent, Event, Fix, WifiEvent
from server.positioning.fingerprint import scan_vector, wknn


@dataclass(frozen=True)
class WknnParams:
    """Parameters of the ``wknn`` engine."""

    k: int = 4  # WKNN neighbours K, papers/002_* eq 3 (as step_ekf)
    # floor under the papers/003_* eq 17 spread, the same value as step_ekf's
    # min_fix_var_m2 so that both engines' fixes claim the same uncertainty for a scan
    min_fix_var_m2: float = 4.0

    def __post_init__(self) -> None:
        if self.k < 1:
            raise ValueError(f"k must be at least 1, got {self.k}")
        if not (math.isfinite(self.min_fix_var_m2) and self.min_fix_var_m2 > 0):
            raise ValueError(
                f"min_fix_var_m2 must be positive and finite, got {self.min_fix_var_m2}"
            )


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

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Flat numeric arrays (0-d int64); ``from_arrays`` inverts exactly."""
        return {
            "floor": np.array(self.floor, dtype=np.int64),
            "n_fixes": np.array(self.n_fixes, dtype=np.int64),
            "last_t_ms": np.array(self.last_t_ms, dtype=np.int64),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, np.ndarray]) -> WknnState:
        """Rebuild a state from ``to_arrays`` output.

        Raises
        ------
        KeyError
            When an array is missing.
        """
        return cls(
            floor=int(arrays["floor"]),
            n_fixes=int(arrays["n_fixes"]),
            last_t_ms=int(arrays["last_t_ms"]),
        )


def initial_state(params: WknnParams) -> WknnState:
    """A state before any fix."""
    del params  # the state does not depend on them
    return WknnState()


def _locate(
    event: WifiEvent | BleEvent, kind: str, maps: SiteMaps, params: WknnParams
) -> Fix | None:
    if maps.radio is None:
        return None
    scan = scan_vector(maps.radio, event.readings, kind)
    found = wknn(maps.radio, scan, k=params.k)
    if found is None:
        return None
    var_m2 = max(found.var_m2, params.min_fix_var_m2)
    return Fix(
        t_ms=event.t_ms,
        x_m=found.x_m,
        y_m=found.y_m,
        floor=found.floor,
        heading_rad=None,
        cov=(var_m2, 0.0, 0.0, var_m2),
        source=kind,
        diagnostics={"n_matched": float(scan.n_matched), "wknn_var_m2": found.var_m2},
    )


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
    fixes: list[Fix] = []
    floor, last_t_ms = state.floor, state.last_t_ms
    for event in sorted(events, key=lambda e: e.t_ms):
        if isinstance(event, WifiEvent):
            fix = _locate(event, "wifi", maps, params)
        elif isinstance(event, BleEvent):
            fix = _locate(event, "ble", maps, params)
        else:
            continue
        last_t_ms = event.t_ms
        if fix is not None:
            fixes.append(fix)
            floor = fix.floor
    new = WknnState(floor=floor, n_fixes=state.n_fixes + len(fixes), last_t_ms=last_t_ms)
    return new, fixes


SPEC = EngineSpec(
    name="wknn",
    params_type=WknnParams,
    initial_state=initial_state,
    from_arrays=WknnState.from_arrays,
    run=run,
    uses=frozenset({"wifi", "ble"}),
)
