"""Floor changes from the phone's barometer: relative pressure, counted in floor spacings.

Absolute pressure says little about the floor: two phones on one floor read up to
0.5 hPa apart and the weather moves the level by up to about 1 hPa an hour, while floors
are 0.3-0.5 hPa apart (about 0.12 hPa per metre near sea level; 0.31-0.33 hPa between
the IPIN 2023 museum's floors). A *change* of pressure over a walk is reliable, so the
detector keeps an *anchor*, the pressure of the floor the phone is on, and compares the
settled pressure with it:

* the pressure is *settled* when the least-squares slope of the raw samples over the last
  ``settle_s`` seconds is below ``max_rate_hpa_s`` (stairs climb at 0.2-0.3 m/s, 0.024-
  0.036 hPa/s, lifts five to ten times faster; a landing half-way up a staircase is
  crossed in fewer seconds than the window, so it does not read as a floor);
* once settled, with ``dp`` the window's mean minus the anchor and ``s`` the floor
  spacing, a change of ``|dp| >= s / 2`` is ``n = -round(dp / s)`` floors (at least one;
  pressure falls going up), reported at the last sample's time, and the anchor moves by
  ``n`` spacings. Counting only settled levels means a change measured before the
  stairs end is never read as fewer floors than it was;
* a smaller settled difference is weather or sensor drift: the anchor follows it with
  time constant ``drift_tau_s``.

The spacing is the site's (``floor_spacing``, learned from walks that change floor with
the barometer on; ``DEFAULT_SPACING_HPA`` where none did). Samples older than the newest
already seen are ignored, so a block sent twice changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from server.positioning.params import Params, Positive
from server.positioning.state_codec import shape

FloatArray = NDArray[np.float64]

# a 3.2 m storey at sea level (0.12 hPa/m); floors of 2.6-4.5 m still count right for
# one floor, and multi-floor rides where the site's spacing was learned
DEFAULT_SPACING_HPA = 0.38


@dataclass(frozen=True)
class BaroParams(Params):
    settle_s: Positive = 3.0  # window of the settled test
    max_rate_hpa_s: Positive = 0.012  # settled: |slope| below this (10 cm/s vertically)
    drift_tau_s: Positive = 60.0  # the anchor follows settled drift this slowly
    min_samples: int = 5  # in the window, for a slope at all


@dataclass(frozen=True)
class BaroState:
    # [t_ms, hPa] of the last settle_s seconds
    window: FloatArray = field(metadata=shape(-1, 2))
    anchor_hpa: float = math.nan  # the current floor's pressure; NaN: none yet
    anchor_t_ms: float = -math.inf  # when the anchor was last moved
    seen_ms: float = -math.inf  # newest sample taken


def initial_barometer() -> BaroState:
    return BaroState(window=np.empty((0, 2)))


PressureWalk = tuple[FloatArray, NDArray[np.int64], NDArray[np.int64]]
"""A walk with the barometer on: ``[t_ms, hPa]`` rows, its waypoints' times and levels."""


@dataclass(frozen=True)
class FloorChange:
    """The phone went ``floors`` floors up (negative: down), settled at ``t_ms``."""

    t_ms: int
    floors: int


def advance(
    state: BaroState, samples: FloatArray, spacing_hpa: float, params: BaroParams
) -> tuple[BaroState, list[FloorChange]]:
    """Take ``samples`` (``[t_ms, hPa]`` rows in time order); the floor changes they
    complete come out (module docstring). The settled test runs after every sample."""
    changes: list[FloorChange] = []
    new = samples[samples[:, 0] > state.seen_ms] if samples.shape[0] else samples
    new = new[np.isfinite(new[:, 1])]
    if new.shape[0] == 0:
        return state, changes
    window = np.vstack([state.window, new])
    settle_ms = 1000.0 * params.settle_s
    t, p = window[:, 0], window[:, 1]
    # least-squares slope and mean of the samples in (t_i - settle_ms, t_i] for every i,
    # from prefix sums (times relative to the first sample, in seconds)
    ts = (t - t[0]) / 1000.0
    zero = np.zeros(1)
    c1, ct, cp = (np.concatenate([zero, np.cumsum(a)]) for a in (np.ones_like(ts), ts, p))
    ctt, ctp = (np.concatenate([zero, np.cumsum(a)]) for a in (ts * ts, ts * p))
    hi = np.arange(1, t.size + 1)
    lo = np.searchsorted(t, t - settle_ms, side="right")
    n = c1[hi] - c1[lo]
    st, sp, stt, stp = (c[hi] - c[lo] for c in (ct, cp, ctt, ctp))
    spread = stt - st * st / np.maximum(n, 1.0)
    slope = (stp - st * sp / np.maximum(n, 1.0)) / np.where(spread > 0, spread, np.inf)
    level = sp / np.maximum(n, 1.0)
    full = (n >= params.min_samples) & (t - t[lo] >= 0.8 * settle_ms)
    settled = full & (np.abs(slope) < params.max_rate_hpa_s)
    settled[: state.window.shape[0]] = False
    anchor, anchor_t = state.anchor_hpa, state.anchor_t_ms
    for i in np.flatnonzero(settled).tolist():
        at, lv = float(t[i]), float(level[i])
        if math.isnan(anchor):
            anchor, anchor_t = lv, at
            continue
        dp = lv - anchor
        if abs(dp) >= 0.5 * spacing_hpa:
            floors = -round(dp / spacing_hpa) or (-1 if dp > 0 else 1)
            changes.append(FloorChange(int(at), floors))
            # on the floor grid, not at the level: a staircase misread as settled half-way
            # is not counted twice, and a spacing a little off leaves drift to follow
            anchor -= floors * spacing_hpa
        else:
            anchor += dp * (1.0 - math.exp(-max(at - anchor_t, 0.0) / 1000.0 / params.drift_tau_s))
        anchor_t = at
    keep = window[t >= t[-1] - settle_ms]
    return (
        replace(state, window=keep, anchor_hpa=anchor, anchor_t_ms=anchor_t, seen_ms=float(t[-1])),
        changes,
    )


def live(state: BaroState, t_ms: int, max_age_s: float) -> bool:
    """Whether the barometer knows the floor's pressure and heard from the phone in the
    last ``max_age_s`` seconds before ``t_ms``: a floor change would have shown."""
    return not math.isnan(state.anchor_hpa) and t_ms - state.seen_ms <= 1000.0 * max_age_s


def floor_spacing(walks: Iterable[PressureWalk]) -> float | None:
    """hPa between adjacent floors from walks that change floor with the barometer on.

    Each walk is ``(pressure, waypoint_t_ms, waypoint_floor)``: ``[t_ms, hPa]`` rows and
    the level at each waypoint. Within one walk (one phone, minutes of weather), each
    floor's pressure is the median of the samples between consecutive waypoints on that
    floor; every pair of floors of the walk gives ``|p_a - p_b| / |a - b|``. The median
    over all pairs of all walks; None when no walk visits two floors.
    """
    estimates: list[float] = []
    for pressure, wt, wf in walks:
        if pressure.shape[0] == 0 or np.unique(wf).size < 2:
            continue
        levels: dict[int, list[float]] = {}
        for a in range(len(wt) - 1):
            if wf[a] != wf[a + 1]:
                continue
            inside = (pressure[:, 0] >= wt[a]) & (pressure[:, 0] <= wt[a + 1])
            levels.setdefault(int(wf[a]), []).extend(pressure[inside, 1].tolist())
        medians = {f: float(np.median(p)) for f, p in levels.items() if p}
        floors = sorted(medians)
        for i, a in enumerate(floors):
            for b in floors[i + 1 :]:
                estimates.append(abs(medians[a] - medians[b]) / (b - a))
    return float(np.median(estimates)) if estimates else None
