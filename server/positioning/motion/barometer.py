"""Floor changes from the phone's barometer: relative pressure, counted in floor spacings.

Absolute pressure says little about the floor: two phones on one floor read up to
0.5 hPa apart and the weather moves the level by up to about 1 hPa an hour, while floors
are 0.3-0.5 hPa apart (about 0.12 hPa per metre near sea level; 0.31-0.33 hPa between
the IPIN 2023 museum's floors). A *change* of pressure over a walk is reliable, so the
detector keeps an *anchor*, the pressure of the floor the phone is on, and compares the
settled pressure with it:

* the pressure is *settled* when the least-squares slope of the raw samples over the last
  ``settle_s`` seconds, plus twice its standard error, is below ``max_rate_hpa_s``
  (stairs climb at 0.2-0.3 m/s, 0.024-0.036 hPa/s, lifts five to ten times faster; a
  noisy or slow barometer settles later rather than on the stairs);
* once settled, with ``dp`` the window's mean minus the anchor and ``s`` the floor
  spacing, a change of ``|dp| >= trigger_spacings * s`` is ``n = -round(dp / s)`` floors
  (at least one; pressure falls going up), reported at the last sample's time, and the
  anchor moves to the settled level. The trigger above half a spacing keeps a landing
  half-way up a staircase from counting as a floor, and re-anchoring at the level rather
  than on a grid of spacings keeps a storey taller or lower than ``s`` from leaving a
  residue that miscounts the next change; a walk that settled for a moment half-way up
  is still one floor in all;
* a smaller settled difference is weather or sensor drift: the anchor follows it with
  time constant ``drift_tau_s``;
* after ``max_gap_s`` without samples the anchor is dropped (the weather, or a ride,
  may have moved the level meanwhile) and set again from the next settled level.

``live`` says whether a scan at a given time may rely on the barometer: it has an anchor,
heard from the phone recently, and has held that anchor for ``hold_after_s`` (a floor
change while it was not listening, at the start or across a gap, is the radio's to see).

The spacing is the site's (``floor_spacing``, learned from walks that change floor with
the barometer on; ``DEFAULT_SPACING_HPA`` where none did). Samples at or before the
newest already seen are ignored, so a block sent twice changes nothing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Annotated

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.model.params import NonNegative, Params, Positive
from server.positioning.model.state_codec import shape

FloatArray = NDArray[np.float64]

# a 3.2 m storey at sea level (0.12 hPa/m); one floor counts right for storeys of 1.9 to
# 4.75 m (0.6 to 1.5 spacings), several floors at once (a lift) need the site's spacing
DEFAULT_SPACING_HPA = 0.38
# what floor_spacing accepts of the walks (storeys of 1.7-6 m)
SPACING_RANGE_HPA = (0.2, 0.72)


@dataclass(frozen=True)
class BaroParams(Params):
    settle_s: Annotated[float, Ge(1.0), Le(10.0)] = 3.0  # window of the settled test
    # settled: |slope| + 2 standard errors below this (17 cm/s vertically)
    max_rate_hpa_s: Positive = 0.02
    trigger_spacings: Annotated[float, Ge(0.5), Le(0.9)] = 0.6
    drift_tau_s: Positive = 60.0  # the anchor follows settled drift this slowly
    max_gap_s: Positive = 10.0  # longer without samples: the anchor is dropped
    min_samples: Annotated[int, Ge(3), Le(1000)] = 3  # in the window, for a slope at all
    hold_after_s: NonNegative = 30.0  # live: the anchor held this long


@dataclass(frozen=True)
class BaroState:
    # [t_ms, hPa] of the last settle_s seconds
    window: FloatArray = field(metadata=shape(-1, 2))
    anchor_hpa: float = math.nan  # the current floor's pressure; NaN: none yet
    anchor_t_ms: float = -math.inf  # when the anchor last moved
    anchor_since_ms: float = math.inf  # when the anchor was set after none
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
    if new[0, 0] - state.seen_ms > 1000.0 * params.max_gap_s:
        state = replace(initial_barometer(), seen_ms=state.seen_ms)
    window = np.vstack([state.window, new])
    settle_ms = 1000.0 * params.settle_s
    t, p = window[:, 0], window[:, 1]
    # least-squares line of the samples in (t_i - settle_ms, t_i] for every i, from prefix
    # sums (times relative to the first sample, in seconds; pressure relative to the first)
    ts, ps = (t - t[0]) / 1000.0, p - p[0]
    zero = np.zeros(1)
    terms = (np.ones_like(ts), ts, ps, ts * ts, ts * ps, ps * ps)
    sums = [np.concatenate([zero, np.cumsum(a)]) for a in terms]
    hi = np.arange(1, t.size + 1)
    lo = np.searchsorted(t, t - settle_ms, side="right")
    n, st, sp, stt, stp, spp = (c[hi] - c[lo] for c in sums)
    m = np.maximum(n, 1.0)
    sxx = stt - st * st / m
    sxy = stp - st * sp / m
    syy = spp - sp * sp / m
    slope = sxy / np.where(sxx > 0, sxx, np.inf)
    residual = np.maximum(syy - slope * sxy, 0.0) / np.maximum(n - 2.0, 1.0)
    se = np.sqrt(residual / np.where(sxx > 0, sxx, np.inf))
    level = p[0] + sp / m
    full = (n >= params.min_samples) & (t - t[lo] >= 0.6 * settle_ms)
    settled = full & (np.abs(slope) + 2.0 * se < params.max_rate_hpa_s)
    settled[: state.window.shape[0]] = False
    anchor, anchor_t, since = state.anchor_hpa, state.anchor_t_ms, state.anchor_since_ms
    for i in np.flatnonzero(settled).tolist():
        at, lv = float(t[i]), float(level[i])
        if math.isnan(anchor):
            anchor, anchor_t, since = lv, at, at
            continue
        dp = lv - anchor
        if abs(dp) >= params.trigger_spacings * spacing_hpa:
            floors = -round(dp / spacing_hpa) or (-1 if dp > 0 else 1)
            changes.append(FloorChange(int(at), floors))
            anchor = lv
        else:
            anchor += dp * (1.0 - math.exp(-max(at - anchor_t, 0.0) / 1000.0 / params.drift_tau_s))
        anchor_t = at
    keep = window[t >= t[-1] - settle_ms]
    after = replace(
        state,
        window=keep,
        anchor_hpa=anchor,
        anchor_t_ms=anchor_t,
        anchor_since_ms=since,
        seen_ms=float(t[-1]),
    )
    return after, changes


def live(state: BaroState, t_ms: int, params: BaroParams) -> bool:
    """Whether a scan at ``t_ms`` may rely on the barometer to report floor changes (module
    docstring)."""
    return (
        not math.isnan(state.anchor_hpa)
        and t_ms - state.anchor_since_ms >= 1000.0 * params.hold_after_s
        and t_ms - state.seen_ms <= 1000.0 * params.max_gap_s
    )


def floor_spacing(walks: Iterable[PressureWalk]) -> float | None:
    """hPa between adjacent floors from walks that change floor with the barometer on.

    Each walk is ``(pressure, waypoint_t_ms, waypoint_floor)``: ``[t_ms, hPa]`` rows and
    the level at each waypoint. Within one walk (one phone, minutes of weather), each
    floor's pressure is the median of the samples between consecutive waypoints on that
    floor; every pair of floors of the walk gives ``|p_a - p_b| / |a - b|``. The median
    over all pairs of all walks, within ``SPACING_RANGE_HPA``; None when no walk visits
    two floors.
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
    if not estimates:
        return None
    low, high = SPACING_RANGE_HPA
    return float(np.clip(np.median(estimates), low, high))
