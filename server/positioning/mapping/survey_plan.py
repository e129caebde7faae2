"""Where to survey a floor: reference points that stay recognisable, after the RP
placement theory of Wang et al. (``papers/004_*``, section "Reference points placement
theory", Definitions 1-2, Theorem 1, Algorithm 1).

Noise distance. With RSS noise ``δ`` (dB) and the log-distance model ``P(d) = P0 - 10 γ
log10 d`` (``path_loss``), two places at distances ``d0 < d`` from an AP are told apart by
it when ``10 γ log10(d / d0) ≥ δ``; the noise distance at ``d0`` is the least such
``d - d0``::

    Δ(d0) = max(d0, 1 m) (10^(δ / (10 γ)) - 1)

(Wang's ``g(d, d0) + φ ≥ δ`` with the wall term ``φ`` left out: walls only make places
easier to tell apart, so this is the longer, safe spacing). It grows with the distance
from the AP: RPs can be dense near an AP and must be sparse far from it. Theorem 1: RPs
closer than that add no accuracy.

Algorithm 1 (``plan``), on the floor graph's grid (``navigation_graph``, gap ``g``):

1. for each located AP and each of the four directions along the grid lines through its
   grid point (for an AP outside the floor, the nearest grid point of the floor's box:
   where its lines first cross the floor): mark the AP's point, then walk outwards and
   mark the first grid point at least ``Δ(d)`` from the previous mark (``d`` that mark's
   distance from the AP), until the line leaves the floor; marks only go on walkable
   points (a blocked point is skipped, the walk goes on);
2. Wang's second rule, "RPs at all possible locations that users may walk to": every
   walkable grid point still farther than its own noise distance (to its nearest AP)
   from every mark is marked, in grid order. The marks are then a maximum RP set in the
   sense of Definition 2 for the nearest AP: no point can be added that is not within
   a noise distance of one.

``δ`` is the map's own noise: the median RSS standard deviation over the floor's
reference points x emitters read at least twice (``noise_from_map``). APs are located by
``path_loss.fit_emitter`` over the floor's RPs, the WiFi emitters heard at the most RPs
first. With ``noise_distance_m`` given, Δ is that constant instead (the toy case of the
theory: marks every Δ along each line).

Expected accuracy: the mean and P90 distance from a walkable grid point to its nearest
mark -- the error of a nearest-RP fix once every planned RP is surveyed and recognisable.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from server.positioning.plan.navigation_graph import FloorGraph
from server.positioning.radio.fingerprints import MISSING_DBM, RadioMap
from server.positioning.radio.path_loss import fit_emitter

FloatArray = NDArray[np.float64]

DEFAULT_NOISE_DB = 4.0
"""δ for a floor whose map has no repeated readings (dB)."""

MIN_NOISE_DB = 0.5
"""δ is never taken below this (dB): RSS is reported in whole dB."""

MIN_RPS_TO_LOCATE = 8  # an emitter heard at fewer RPs is not located
EXPONENT_RANGE = (1.5, 6.0)  # fitted path-loss exponents are held in this range


@dataclass(frozen=True)
class AccessPoint:
    xy: tuple[float, float]
    exponent: float
    key: str = ""


@dataclass(frozen=True)
class SurveyPlan:
    """Planned RP positions and what they promise.

    Attributes
    ----------
    points : ndarray, shape (n, 2)
        Planned RPs (m), walkable grid points.
    from_aps : ndarray, shape (n,), bool
        Marked by Algorithm 1's lines (True) or by the coverage pass (False).
    noise_db : float
        δ used.
    noise_source : str
        ``"map"``, ``"default"`` or ``"given"`` (a constant noise distance).
    aps : tuple of AccessPoint
    expected_error_m, expected_error_p90_m : float
        Mean and P90 distance from a walkable grid point to its nearest planned RP.
    """

    points: FloatArray
    from_aps: NDArray[np.bool_]
    noise_db: float
    noise_source: str
    aps: tuple[AccessPoint, ...]
    expected_error_m: float
    expected_error_p90_m: float


def noise_distance(d0_m: FloatArray | float, noise_db: float, exponent: float) -> FloatArray:
    """Δ(d0) of the module docstring (m)."""
    d0 = np.maximum(np.asarray(d0_m, dtype=np.float64), 1.0)
    out: FloatArray = d0 * (10.0 ** (noise_db / (10.0 * exponent)) - 1.0)
    return out


def noise_from_map(radio: RadioMap | None, floor: int) -> float | None:
    """Median RSS standard deviation (dB) over the floor's RP x emitter cells read at least
    twice; None when there are none."""
    if radio is None:
        return None
    rows = radio.rp_floor == floor
    var = radio.var_db2[rows][radio.count[rows] >= 2]
    return float(np.median(np.sqrt(var))) if var.size else None


def locate_aps(radio: RadioMap | None, floor: int, max_aps: int = 100) -> tuple[AccessPoint, ...]:
    """WiFi emitters of the floor located by their path loss over its RPs."""
    if radio is None:
        return ()
    rows = np.flatnonzero(radio.rp_floor == floor)
    heard = radio.mean_dbm[rows] > MISSING_DBM
    wifi = np.array([key.startswith("wifi:") for key in radio.emitters])
    counts = heard.sum(axis=0) * wifi
    out: list[AccessPoint] = []
    for col in np.argsort(-counts, kind="stable")[:max_aps]:
        if counts[col] < MIN_RPS_TO_LOCATE:
            break
        where = heard[:, col]
        fit = fit_emitter(
            radio.rp_xy[rows[where]].astype(np.float64),
            radio.mean_dbm[rows[where], col].astype(np.float64),
        )
        if fit is None or not np.isfinite(fit.xy).all():
            continue
        exponent = float(np.clip(fit.exponent, *EXPONENT_RANGE))
        out.append(AccessPoint((float(fit.xy[0]), float(fit.xy[1])), exponent, radio.emitters[col]))
    return tuple(out)


def plan(
    graph: FloorGraph,
    aps: tuple[AccessPoint, ...],
    noise_db: float,
    noise_distance_m: float | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Algorithm 1 and the coverage pass (module docstring): planned points and whether
    each came from an AP's lines."""
    g = graph.spacing_m
    cells = np.rint(graph.xy / g - 0.5).astype(np.int64)
    walkable = {(int(c[0]), int(c[1])) for c in cells}
    lo, hi = cells.min(axis=0), cells.max(axis=0)

    def spacing(d0: float, exponent: float) -> float:
        if noise_distance_m is not None:
            return noise_distance_m
        return float(noise_distance(d0, noise_db, exponent))

    marked: dict[tuple[int, int], bool] = {}
    for ap in aps:
        # the AP's grid point, or the nearest one of the floor's box for an AP outside it:
        # the lines then start where they first cross the floor (Algorithm 1's "else")
        c0 = np.clip(np.rint(np.asarray(ap.xy) / g - 0.5).astype(np.int64), lo, hi)
        centre = (c0 + 0.5) * g
        if (c0[0], c0[1]) in walkable:
            marked[(int(c0[0]), int(c0[1]))] = True
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            last_d = float(np.hypot(*(centre - ap.xy)))
            last = centre
            k = 1
            while True:
                c = (int(c0[0] + k * dx), int(c0[1] + k * dy))
                if not (lo[0] <= c[0] <= hi[0] and lo[1] <= c[1] <= hi[1]):
                    break
                k += 1
                if c not in walkable:
                    continue
                xy = (np.array(c) + 0.5) * g
                if float(np.hypot(*(xy - last))) + 1e-9 >= spacing(last_d, ap.exponent):
                    marked[c] = True
                    last, last_d = xy, float(np.hypot(*(xy - ap.xy)))
    # coverage: every walkable point farther than its noise distance from every mark
    if aps:
        ap_xy = np.array([a.xy for a in aps])
        ap_n = np.array([a.exponent for a in aps])
        dist, nearest = cKDTree(ap_xy).query(graph.xy)
        own = np.array(
            [spacing(float(d), float(ap_n[i])) for d, i in zip(dist, nearest, strict=True)]
        )
    else:
        own = np.full(graph.n, noise_distance_m if noise_distance_m is not None else 3.0 * g)
    chosen = [((np.array(c) + 0.5) * g) for c in marked]
    vertices = graph.tree
    reach = float(own.max()) if own.size else 0.0
    covered = np.zeros(graph.n, dtype=bool)

    def cover(mark: FloatArray) -> None:
        near = np.asarray(vertices.query_ball_point(mark, reach), dtype=np.int64)
        if near.size:
            d = np.hypot(*(graph.xy[near] - mark).T)
            covered[near[(d + 1e-9 < own[near]) | (d < 1e-9)]] = True  # and the mark's own

    for mark in chosen:
        cover(mark)
    extra: list[FloatArray] = []
    for i in np.lexsort((graph.xy[:, 0], graph.xy[:, 1])):
        if not covered[i]:
            extra.append(graph.xy[i])
            cover(graph.xy[i])
    from_aps = [True] * len(chosen)
    points = np.array(chosen + extra, dtype=np.float64).reshape(-1, 2)
    flags = np.array(from_aps + [False] * len(extra), dtype=bool)
    return points, flags


def survey_plan(
    graph: FloorGraph,
    radio: RadioMap | None,
    floor: int,
    noise_distance_m: float | None = None,
    max_aps: int = 100,
) -> SurveyPlan:
    """The plan of a floor from its graph and what its radio map shows (module docstring)."""
    found = noise_from_map(radio, floor)
    noise_db = max(found, MIN_NOISE_DB) if found is not None else DEFAULT_NOISE_DB
    source = (
        "given" if noise_distance_m is not None else ("map" if found is not None else "default")
    )
    aps = locate_aps(radio, floor, max_aps)
    points, flags = plan(graph, aps, noise_db, noise_distance_m)
    gaps = cKDTree(points).query(graph.xy)[0] if points.size else np.full(graph.n, np.inf)
    return SurveyPlan(
        points=points,
        from_aps=flags,
        noise_db=noise_db,
        noise_source=source,
        aps=aps,
        expected_error_m=float(np.mean(gaps)),
        expected_error_p90_m=float(np.percentile(gaps, 90)),
    )
