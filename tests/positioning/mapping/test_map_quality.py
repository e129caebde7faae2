"""Map quality of one floor from hand-built maps and points: coverage with and without a
plan, the cells' samples and variances, freshness, and the emitters heard."""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.magnetic.field_grid import MagneticGrid
from server.positioning.mapping.map_quality import (
    Coverage,
    Emitters,
    FloorFigures,
    Freshness,
    MagneticCells,
    Percentiles,
    QualityParams,
    QualityPoint,
    RadioCells,
    floor_figures,
)
from tests.support.quality_floor import polygon

NAN = float("nan")
NOW = datetime(2024, 3, 1, 12, 0, tzinfo=UTC)
DAY_MS = 86_400_000
T0_MS = 1_700_000_000_000


# 4 m x 3 m of floor from (2, 1) to (6, 4), a 1 m pillar at (3, 2)-(4, 3): 12 - 1 = 11
# walkable 1 m cells, 48 - 4 = 44 walkable 0.5 m cells; the plan's lattice starts at (2, 1)
PLAN = {
    "type": "FeatureCollection",
    "features": [polygon(2, 1, 6, 4, "walkable"), polygon(3, 2, 4, 3, "obstacle")],
}


def walkable_1m(col: int, row: int) -> bool:
    """Whether the 1 m cell (col, row) of PLAN is walkable (its centre is)."""
    return 2 <= col < 6 and 1 <= row < 4 and (col, row) != (3, 2)


def figures(
    rp_xy: Sequence[tuple[float, float]] = (),
    count: Sequence[Sequence[int]] | None = None,
    var: Sequence[Sequence[float]] | None = None,
    *,
    plan: dict[str, Any] | None = None,
    seen: set[tuple[str, str]] | None = None,
    grid: MagneticGrid | None = None,
    points: Sequence[QualityPoint] = (),
    params: QualityParams | None = None,
) -> FloorFigures:
    xy = np.array(rp_xy, dtype=np.float64).reshape(-1, 2)
    counts = (
        np.zeros((xy.shape[0], 1), np.int32) if count is None else np.array(count, dtype=np.int32)
    )
    return floor_figures(
        plan,
        xy,
        counts,
        None if var is None else np.array(var, dtype=np.float64),
        seen or set(),
        grid,
        points,
        params or QualityParams(),
        NOW,
    )


def point(
    x: float,
    y: float,
    *,
    days_ago: float = 0.0,
    upload: str | None = None,
    t_ms: int | None = None,
    wifi: Sequence[tuple[str, float]] = (),
    ble: Sequence[tuple[str, float]] = (),
) -> QualityPoint:
    readings: dict[str, Any] = {"wifi": [[k, v] for k, v in wifi], "ble": [[k, v] for k, v in ble]}
    return QualityPoint(x, y, t_ms, NOW - timedelta(days=days_ago), upload, readings)


# ---- coverage -----------------------------------------------------------------------------


def test_radio_coverage_is_the_share_of_walkable_cells_holding_an_rp() -> None:
    rps = [
        (2.5, 1.5),  # cell (2, 1)
        (2.9, 1.1),  # the same cell again
        (3.5, 2.5),  # under the pillar: not walkable, not counted
        (5.5, 3.5),  # cell (5, 3)
        (0.5, 0.5),  # left of and below the plan
        (10.0, 10.0),  # beyond it
    ]
    f = figures(rps, plan=PLAN)
    assert f.coverage.walkable_area_known is True
    assert f.coverage.radio == pytest.approx(2 / 11)
    # every walkable cell: full coverage, the pillar's RP changes nothing
    everywhere = [(c + 0.5, r + 0.5) for c in range(2, 6) for r in range(1, 4)]
    assert figures(everywhere, plan=PLAN).coverage.radio == pytest.approx(1.0)
    # no RP on a planned floor: nothing covered
    assert figures(plan=PLAN).coverage.radio == 0.0


def test_without_a_plan_radio_coverage_is_over_the_rps_bounding_box() -> None:
    # three of the four 1 m cells of [0, 2) x [0, 2)
    f = figures([(0.5, 0.5), (1.5, 0.5), (0.5, 1.5)])
    assert f.coverage.walkable_area_known is False
    assert f.coverage.radio == pytest.approx(3 / 4)
    # cells (-1, 0) and (1, 2): a box of 3 x 3 cells (negative coordinates floor down)
    assert figures([(-0.5, 0.5), (1.5, 2.5)]).coverage.radio == pytest.approx(2 / 9)
    # one RP fills its own box; no RP covers nothing
    assert figures([(7.2, -3.4)]).coverage.radio == 1.0
    assert figures().coverage.radio == 0.0


@pytest.mark.parametrize(
    "unusable",
    [
        None,
        {},
        {"type": "FeatureCollection", "features": []},  # no walkable polygon
        # an obstacle over all the walkable area
        {
            "type": "FeatureCollection",
            "features": [polygon(0, 0, 1, 1, "walkable"), polygon(-1, -1, 2, 2, "obstacle")],
        },
    ],
)
def test_a_missing_or_unusable_plan_falls_back_to_the_maps_extent(
    unusable: dict[str, Any] | None,
) -> None:
    f = figures([(0.5, 0.5), (2.5, 0.5)], plan=unusable)
    assert f.coverage.walkable_area_known is False
    assert f.coverage.radio == pytest.approx(2 / 3)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(st.floats(-2.0, 9.0, allow_nan=False), st.floats(-2.0, 7.0, allow_nan=False)),
        max_size=20,
    )
)
def test_radio_coverage_counts_the_walkable_cells_with_an_rp(
    rps: list[tuple[float, float]],
) -> None:
    cells = {(math.floor(x), math.floor(y)) for x, y in rps}
    expected = sum(walkable_1m(*c) for c in cells) / 11
    assert figures(rps, plan=PLAN).coverage.radio == pytest.approx(expected)


def grid() -> MagneticGrid:
    """0.5 m cells from (3, 2), 2 rows x 3 columns: columns 0 and 1 lie on PLAN's pillar.
    Known: (0, 0) and (1, 1) on the pillar, (0, 2) and (1, 2) beside it."""
    f32 = np.float32
    return MagneticGrid(
        origin_m=(3.0, 2.0),
        cell_m=0.5,
        magnitude=np.array([[40.0, NAN, 41.0], [NAN, 42.0, 43.0]], dtype=f32),
        # the single sample of (0, 0) carries a stored value, not a variance
        var=np.array([[7.0, NAN, 0.5], [NAN, 2.0, 4.0]], dtype=f32),
        count=np.array([[1, 0, 3], [0, 2, 5]], dtype=np.int32),
        horizontal=None,
        vertical=None,
    )


def test_magnetic_coverage_and_cells_from_the_grid() -> None:
    planned = figures(plan=PLAN, grid=grid())
    # the two known cells beside the pillar, of the plan's 44 walkable half-metre cells
    assert planned.coverage.magnetic == pytest.approx(2 / 44)
    # without a plan: the grid's own cells
    assert figures(grid=grid()).coverage.magnetic == pytest.approx(4 / 6)
    cells = planned.magnetic_cells
    assert cells.known_cells == 4
    # samples of the known cells: 1, 3, 2, 5
    assert cells.samples_per_cell == pytest.approx(Percentiles(1.3, 2.5, 4.4))
    # variance only where a cell holds 2 or more: 0.5, 2, 4
    assert cells.var_ut2 == pytest.approx(Percentiles(0.8, 2.0, 3.6))


def test_a_floor_without_a_magnetic_grid() -> None:
    f = figures(plan=PLAN)
    assert f.coverage.magnetic == 0.0
    assert f.magnetic_cells == MagneticCells(known_cells=0, samples_per_cell=None, var_ut2=None)


def test_a_grid_of_single_samples_has_no_variance() -> None:
    single = MagneticGrid(
        origin_m=(0.0, 0.0),
        cell_m=0.5,
        magnitude=np.array([[40.0, 41.0]], dtype=np.float32),
        var=np.array([[NAN, NAN]], dtype=np.float32),
        count=np.array([[1, 1]], dtype=np.int32),
        horizontal=None,
        vertical=None,
    )
    cells = figures(grid=single).magnetic_cells
    assert cells == MagneticCells(2, Percentiles(1.0, 1.0, 1.0), None)


# ---- radio cells ------------------------------------------------------------------------


def test_radio_cells_readings_emitters_and_variances_per_rp() -> None:
    count = [[2, 0, 1], [4, 3, 0], [1, 1, 1]]  # RP x emitter
    var = [[1.0, 9.0, 9.0], [2.0, 5.0, 9.0], [9.0, 9.0, 9.0]]
    cells = figures([(0.5, 0.5), (1.5, 0.5), (2.5, 0.5)], count, var).radio_cells
    assert cells.n_reference_points == 3
    # readings per RP 3, 7, 3; emitters per RP 2, 2, 3
    assert cells.readings_per_rp == pytest.approx(Percentiles(3.0, 3.0, 6.2))
    assert cells.emitters_per_rp == pytest.approx(Percentiles(2.0, 2.0, 2.8))
    # only the RP x emitter pairs of 2 readings or more: 1, 2, 5 (the 9s are defaults)
    assert cells.var_db2 == pytest.approx(Percentiles(1.2, 2.0, 4.4))


def test_radio_cell_variances_skip_unknown_values_and_missing_arrays() -> None:
    count = [[2, 2], [3, 1]]
    cells = figures([(0.5, 0.5), (1.5, 0.5)], count, [[NAN, 4.0], [6.0, 1.0]]).radio_cells
    assert cells.var_db2 == pytest.approx(Percentiles(4.2, 5.0, 5.8))
    assert figures([(0.5, 0.5), (1.5, 0.5)], count, None).radio_cells.var_db2 is None
    # no pair of 2 readings: no variance at all
    ones = figures([(0.5, 0.5)], [[1, 1]], [[3.0, 3.0]]).radio_cells
    assert ones.var_db2 is None
    assert ones.readings_per_rp == Percentiles(2.0, 2.0, 2.0)


def test_a_floor_without_rps() -> None:
    cells = floor_figures(
        None,
        np.zeros((0, 2)),
        np.zeros((0, 0), np.int32),
        None,
        set(),
        None,
        (),
        QualityParams(),
        NOW,
    )
    assert cells == FloorFigures(
        Coverage(radio=0.0, magnetic=0.0, walkable_area_known=False),
        RadioCells(0, None, None, None),
        MagneticCells(0, None, None),
        Freshness(None, None, 0, None, 0, 0, 0),
        Emitters(seen=0, fixed=0, retired=0, positions=(), unlocated=0),
    )


# ---- freshness --------------------------------------------------------------------------


def test_freshness_of_the_floor_s_points() -> None:
    points = [
        point(0.2, 0.2, days_ago=10),  # surveyed, cell (0, 0)
        point(0.7, 0.9, days_ago=2, upload="u1"),  # cell (0, 0): its newest point
        point(3.5, 1.5, days_ago=4, upload="u1"),  # cell (3, 1)
        point(-0.5, 0.5, days_ago=1, upload="u2"),  # cell (-1, 0)
        point(3.2, 1.1, days_ago=-1),  # surveyed, cell (3, 1), dated in the future
    ]
    fresh = figures(points=points).freshness
    assert fresh.newest == NOW + timedelta(days=1)
    assert fresh.oldest == NOW - timedelta(days=10)
    assert fresh.n_cells == 3
    # newest point per cell: 2 days, 1 day, and the future one's age clamped to 0
    assert fresh.cell_age_days == pytest.approx(Percentiles(0.2, 1.0, 1.8))
    assert fresh.n_points == 5
    assert fresh.n_surveyed_points == 2
    assert fresh.n_uploads == 2


def test_freshness_of_a_floor_without_points() -> None:
    assert figures().freshness == Freshness(None, None, 0, None, 0, 0, 0)


# ---- emitters ---------------------------------------------------------------------------


def test_retired_emitters_are_seen_but_not_heard_in_the_window() -> None:
    seen = {("wifi", "aa"), ("wifi", "bb"), ("ble", "cc"), ("wifi", "dd"), ("wifi", "ee")}
    points = [
        point(0.5, 0.5, days_ago=0, wifi=[("AA", -60.0)]),  # the newest point
        point(1.5, 0.5, days_ago=5, ble=[("CC", -70.0)]),  # keys are compared lower-case
        point(2.5, 0.5, days_ago=30, wifi=[("ee", -70.0)]),  # on the window's edge: in it
        point(3.5, 0.5, days_ago=40, wifi=[("bb", -65.0)]),  # before the window
        point(4.5, 0.5, days_ago=1, ble=[("dd", -65.0)]),  # dd as a beacon, not as WiFi
    ]
    em = figures(seen=seen, points=points).emitters
    assert em.seen == 5
    assert em.retired == 2  # bb and the WiFi dd
    wider = figures(seen=seen, points=points, params=QualityParams(retired_after_days=45))
    assert wider.emitters.retired == 1  # dd
    # the window ends at the newest point, not now: all of them 100 days older
    older = [
        QualityPoint(p.x_m, p.y_m, p.t_ms, p.created_at - timedelta(days=100), None, p.readings)
        for p in points
    ]
    assert figures(seen=seen, points=older).emitters.retired == 2
    # no points: every emitter seen is retired
    assert figures(seen=seen).emitters.retired == 5


def _daily(key: str, kind: str, *, timed: bool) -> list[QualityPoint]:
    """Five points on five days, within a 2 m square, hearing ``key`` at -50 dBm: a fixed
    AP by IV-E1 when they carry a time (heard on > 3 days, strong, clustered)."""
    places = [(1.0, 1.0), (2.0, 1.0), (1.0, 2.0), (2.0, 2.0), (1.5, 1.5)]
    return [
        QualityPoint(
            x,
            y,
            T0_MS + k * DAY_MS if timed else None,
            NOW - timedelta(days=5 - k),
            None,
            {kind: [[key, -50.0]]},
        )
        for k, (x, y) in enumerate(places)
    ]


def test_fixed_aps_are_the_timed_wifi_readings_of_iv_e1() -> None:
    assert figures(points=_daily("aa", "wifi", timed=True)).emitters.fixed == 1
    # without times the days cannot be told; beacons are not APs
    assert figures(points=_daily("aa", "wifi", timed=False)).emitters.fixed == 0
    assert figures(points=_daily("cc", "ble", timed=True)).emitters.fixed == 0
    # heard on three days only
    assert figures(points=_daily("aa", "wifi", timed=True)[:3]).emitters.fixed == 0
    # never stronger than -55 dBm
    weak = [
        QualityPoint(p.x_m, p.y_m, p.t_ms, p.created_at, None, {"wifi": [["aa", -60.0]]})
        for p in _daily("aa", "wifi", timed=True)
    ]
    assert figures(points=weak).emitters.fixed == 0


AP_A = (5.0, 5.0)  # WiFi "aa": P0 -40 dBm, exponent 2.5
AP_B = (2.0, 8.0)  # beacon "bb": P0 -60 dBm, exponent 2.0
GRID_XY = [(x, y) for x in (1.0, 4.0, 8.0) for y in (2.0, 6.0, 9.0)]


def _log_distance(xy: tuple[float, float], ap: tuple[float, float], p0: float, n: float) -> float:
    return p0 - 10.0 * n * math.log10(math.dist(xy, ap))


def _emitter_points() -> list[QualityPoint]:
    """Nine points on a 3 x 3 grid hearing "AA" and "bb" by the log-distance model; five on
    a line hearing "cc" (collinear: no fit), two hearing "dd" (too few), "ee" only as a
    reading without a value."""
    points = [
        point(
            x,
            y,
            wifi=[("AA", _log_distance((x, y), AP_A, -40.0, 2.5))],
            ble=[("bb", _log_distance((x, y), AP_B, -60.0, 2.0))],
        )
        for x, y in GRID_XY
    ]
    points += [point(float(x), 12.0, wifi=[("cc", -50.0 - x)]) for x in range(5)]
    points += [point(float(x), 13.0, wifi=[("dd", -70.0)]) for x in range(2)]
    points += [point(0.0, 14.0, wifi=[("ee", NAN)])]
    return points


def test_positions_of_the_most_read_emitters() -> None:
    em = figures(points=_emitter_points()).emitters
    # ranked by readings (9, 9, 5, 2; ties by kind and key): bb, aa fitted; cc, dd not
    assert [(p.kind, p.key) for p in em.positions] == [("ble", "bb"), ("wifi", "aa")]
    assert em.unlocated == 2  # "ee" has no finite reading: not ranked at all
    bb, aa = em.positions
    assert (aa.x_m, aa.y_m) == pytest.approx(AP_A, abs=1e-6)
    assert aa.p0_dbm == pytest.approx(-40.0, abs=1e-6)
    assert aa.exponent == pytest.approx(2.5, abs=1e-6)
    assert aa.n == 9
    assert aa.residual_rms_db == pytest.approx(0.0, abs=1e-6)
    assert aa.xy_std_m is not None
    assert max(aa.xy_std_m) < 1e-6
    assert (bb.x_m, bb.y_m) == pytest.approx(AP_B, abs=1e-6)
    assert bb.p0_dbm == pytest.approx(-60.0, abs=1e-6)
    assert bb.exponent == pytest.approx(2.0, abs=1e-6)
    assert bb.n == 9


@pytest.mark.parametrize(
    ("max_emitters", "located", "unlocated"),
    [
        (0, [], 0),
        (1, ["bb"], 0),  # the tie of 9 readings goes to the beacon ("ble" < "wifi")
        (2, ["bb", "aa"], 0),
        (3, ["bb", "aa"], 1),  # cc's readings lie on a line
        (50, ["bb", "aa"], 2),
    ],
)
def test_only_the_max_emitters_most_read_are_fitted(
    max_emitters: int, located: list[str], unlocated: int
) -> None:
    params = QualityParams(max_emitters=max_emitters)
    em = figures(points=_emitter_points(), params=params).emitters
    assert [p.key for p in em.positions] == located
    assert em.unlocated == unlocated
