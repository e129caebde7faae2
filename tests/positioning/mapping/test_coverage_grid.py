"""The coverage grid of a floor from hand-built maps and points: the cells laid over a plan
(a cell touching the walkable area is not in it), over the data without one, each cell's
readings, emitters, variance and age, and the fix error the map can be expected to give."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.positioning.mapping.coverage_grid import (
    DAY_S,
    TooManyCells,
    coverage_grid,
    rows_of,
)
from server.positioning.radio import fix_error
from server.positioning.radio.fix_error import EDGES, FixErrorModel
from tests.support.quality_floor import polygon

NOW_S = 1_709_294_400.0  # 2024-03-01 12:00 UTC

# an L of floor: 4 m x 4 m from the origin and a 2 m wide arm up to y = 8. At 2 m cells the
# grid is 4 rows x 2 columns; the cells right of the arm, [2, 4) x [4, 8), only touch it
L_PLAN = {
    "type": "FeatureCollection",
    "features": [polygon(0, 0, 4, 4, "walkable"), polygon(0, 4, 2, 8, "walkable")],
}
L_IN_AREA = [[True, True], [True, True], [True, False], [True, False]]


def grid(
    plan: dict[str, Any] | None = L_PLAN,
    rp_xy: Any = (),
    count: Any = (),
    var: Any = None,
    kinds: Any = (),
    point_xy: Any = (),
    created_s: Any = (),
    model: FixErrorModel = fix_error.DEFAULT,
    cell_m: float = 2.0,
    **kw: Any,
) -> Any:
    rp = np.asarray(rp_xy, dtype=np.float64).reshape(-1, 2)
    n = np.asarray(count, dtype=np.int32).reshape(rp.shape[0], len(kinds))
    v = np.zeros(n.shape) if var is None else np.asarray(var, dtype=np.float64)
    return coverage_grid(
        plan,
        rp,
        n,
        v,
        list(kinds),
        np.asarray(point_xy, dtype=np.float64).reshape(-1, 2),
        np.asarray(created_s, dtype=np.float64),
        NOW_S,
        model,
        cell_m,
        **kw,
    )


def test_the_grid_covers_the_walkable_area_of_the_plan() -> None:
    g = grid()
    assert g.walkable_area_known
    assert g.origin_m == (0.0, 0.0)
    assert g.cell_m == 2.0
    assert g.shape == (4, 2)
    # a cell sharing only an edge with the arm is not in the area
    assert g.in_area.tolist() == L_IN_AREA
    # no data: every cell is there, empty
    assert not g.readings.any()
    assert not g.points.any()
    assert not g.emitters.any()
    for figure in (g.var_db2, g.age_days, g.nearest_rp_m, g.expected_error_m):
        assert np.isnan(figure).all()


def test_cells_partly_walkable_count_and_the_lattice_is_of_whole_cells() -> None:
    # the L at 3 m cells: origin 0, ceil(4 / 3) = 2 columns, ceil(8 / 3) = 3 rows; the cell
    # [3, 6) x [3, 6) holds the walkable square [3, 4) x [3, 4); [3, 6) x [6, 9) none
    g = grid(cell_m=3.0)
    assert g.shape == (3, 2)
    assert g.in_area.tolist() == [[True, True], [True, True], [True, False]]
    # a plan away from the origin starts at the multiple of the cell below it
    shifted = {"type": "FeatureCollection", "features": [polygon(5.5, -3.2, 9, -1, "room")]}
    g = grid(shifted)
    assert g.origin_m == (4.0, -4.0)
    assert g.shape == (2, 3)  # y from -4 to 0, x from 4 to 10
    assert g.in_area.all()


def test_a_plan_of_many_rooms_spans_tiles() -> None:
    # 40 m x 40 m of floor with 16 units [10 i + 2, 10 i + 8.3] x [10 j + 2, 10 j + 8.7]:
    # each fills 6 x 6 whole 1 m cells, and the cells its far edges cut stay in the area
    # (a grid of 40 x 40 cells: many tiles of the boundary's clipping)
    units = [
        polygon(10 * i + 2, 10 * j + 2, 10 * i + 8.3, 10 * j + 8.7, "unit")
        for i in range(4)
        for j in range(4)
    ]
    plan = {"type": "FeatureCollection", "features": [polygon(0, 0, 40, 40, "walkable"), *units]}
    g = grid(plan, cell_m=1.0)
    assert g.shape == (40, 40)
    assert int(g.in_area.sum()) == 40 * 40 - 16 * 6 * 6
    assert not g.in_area[2:8, 12:18].any()  # unit (1, 0)
    assert g.in_area[8, 12:18].all()  # its top row of cells, 0.3 m of it walkable
    assert g.in_area[1, 12:18].all()  # below it: only touching


def test_readings_emitters_and_variance_per_cell() -> None:
    # three RPs, emitters (wifi a, wifi b, ble c): two in cell [0, 2) x [0, 2), one in
    # [2, 4) x [2, 4) and one outside the plan's grid, which is left out
    g = grid(
        rp_xy=[(0.5, 0.5), (1.5, 1.0), (3.0, 3.0), (30.0, 30.0)],
        count=[[2, 1, 0], [3, 0, 1], [0, 0, 5], [9, 9, 9]],
        var=[[4.0, 7.0, 0.0], [2.0, 0.0, 9.0], [0.0, 0.0, 1.5], [1.0, 1.0, 1.0]],
        kinds=["wifi", "wifi", "ble"],
    )
    assert g.readings.tolist() == [[2 + 1 + 3 + 1, 0], [0, 5], [0, 0], [0, 0]]
    # heard in the first cell: a, b (first RP), a, c (second): three distinct
    assert g.emitters.tolist() == [[3, 0], [0, 1], [0, 0], [0, 0]]
    # entries of 2 readings or more: (4 + 2) / 2 in the first cell, 1.5 in the other;
    # a single reading's variance (7, 9) is left out
    assert rows_of(g.var_db2) == [[3.0, None], [None, 1.5], [None, None], [None, None]]


def test_points_and_the_age_of_the_newest_per_cell() -> None:
    g = grid(
        point_xy=[(0.5, 0.5), (1.9, 1.9), (1.0, 7.0), (2.0, 0.0)],
        created_s=[NOW_S - 3 * DAY_S, NOW_S - 1.5 * DAY_S, NOW_S - 10 * DAY_S, NOW_S + 60],
    )
    # a point on the edge x = 2 belongs to the cell on its right
    assert g.points.tolist() == [[2, 1], [0, 0], [0, 0], [1, 0]]
    # the newest of a cell counts; a point from the future is 0 days old
    assert rows_of(g.age_days) == [[1.5, 0.0], [None, None], [None, None], [10.0, None]]


def test_the_expected_error_grows_with_the_distance_to_the_nearest_rp() -> None:
    # one RP at (1, 1) hearing 4 WiFi APs: the default σ is 4 + 12 / sqrt(4) = 10 m
    g = grid(rp_xy=[(1.0, 1.0)], count=[[1, 1, 1, 1]], kinds=["wifi"] * 4)
    centres = [[(1 + 2 * j, 1 + 2 * i) for j in range(2)] for i in range(4)]
    distance = np.array([[math.dist(c, (1, 1)) for c in row] for row in centres])
    np.testing.assert_allclose(g.nearest_rp_m, distance)
    np.testing.assert_allclose(g.expected_error_m, np.sqrt(2 * 10.0**2 + distance**2))
    assert g.expected_error_m[0, 0] == pytest.approx(math.sqrt(200.0))
    # the far end of the arm, 6 m up: worse than the RP's own cell
    assert g.expected_error_m[3, 0] == pytest.approx(math.sqrt(200.0 + 36.0))


def test_the_error_takes_the_better_scan_kind_and_the_learned_table() -> None:
    # learned: WiFi σ 3 m from 8 APs on (bins of EDGES), 9 m below; BLE not learned (the
    # default, 4 + 12 / sqrt(n))
    wifi = tuple(9.0 if edge < 8 else 3.0 for edge in EDGES)
    model = FixErrorModel(sigma_m={"wifi": wifi}, counts={"wifi": (100,) * len(EDGES)})
    kinds = ["wifi"] * 8 + ["ble"] * 4
    # RP 0 at (1, 1): 8 APs and 4 beacons -> min(3, 10) = 3; RP 1 at (1, 7): 2 APs and
    # 4 beacons -> min(9, 10) = 9; RP 2 at (3, 3): beacons alone -> 10
    count = np.zeros((3, 12), dtype=np.int32)
    count[0, :] = 1
    count[1, :2] = count[1, 8:] = 1
    count[2, 8:] = 1
    g = grid(rp_xy=[(1, 1), (1, 7), (3, 3)], count=count, kinds=kinds, model=model)
    assert g.expected_error_m[0, 0] == pytest.approx(3.0 * math.sqrt(2))
    assert g.expected_error_m[3, 0] == pytest.approx(9.0 * math.sqrt(2))
    assert g.expected_error_m[1, 1] == pytest.approx(10.0 * math.sqrt(2))
    # an RP that hears nothing: the σ of one emitter of the worse kind (BLE's default 16)
    g = grid(rp_xy=[(1, 1)], count=np.zeros((1, 12)), kinds=kinds, model=model)
    assert g.expected_error_m[0, 0] == pytest.approx(16.0 * math.sqrt(2))


def test_without_a_plan_the_grid_covers_the_data() -> None:
    # RPs and points from (1, 0.5) to (4, 3): cells of 2 m from (0, 0); x = 4 lies on the
    # edge of a third column
    g = grid(
        plan=None,
        rp_xy=[(1.0, 0.5), (3.0, 3.0)],
        count=[[1], [2]],
        kinds=["wifi"],
        point_xy=[(4.0, 1.0)],
        created_s=[NOW_S],
    )
    assert not g.walkable_area_known
    assert g.origin_m == (0.0, 0.0)
    assert g.shape == (2, 3)
    assert g.in_area.all()
    assert g.readings.tolist() == [[1, 0, 0], [0, 2, 0]]
    assert g.points.tolist() == [[0, 0, 1], [0, 0, 0]]
    # a plan without a walkable polygon is no plan
    unusable = {"type": "FeatureCollection", "features": [polygon(0, 0, 9, 9, "obstacle")]}
    assert grid(plan=unusable, rp_xy=[(1.0, 0.5)], count=[[1]], kinds=["wifi"]).shape == (1, 1)


def test_a_floor_without_plan_or_data_has_no_cells() -> None:
    g = grid(plan=None)
    assert g.shape == (0, 0)
    assert not g.walkable_area_known
    assert rows_of(g.expected_error_m) == []


def test_too_many_cells_names_a_size_that_fits() -> None:
    # the L at 0.5 m: 8 x 16 = 128 cells
    with pytest.raises(TooManyCells) as raised:
        grid(cell_m=0.5, max_cells=20)
    fitting = raised.value.min_cell_m
    assert "128 cells" in str(raised.value)
    assert grid(cell_m=fitting, max_cells=20).in_area.size <= 20
    with pytest.raises(TooManyCells):
        grid(cell_m=fitting - 0.01, max_cells=20)
    with pytest.raises(ValueError, match="positive"):
        grid(cell_m=0.0)


def test_rows_of_rounds_and_writes_none_for_unknown() -> None:
    assert rows_of(np.array([[1.234, np.nan]]), 2) == [[1.23, None]]
    assert rows_of(np.array([[1, 2]])) == [[1, 2]]
    assert rows_of(np.array([[True, False]])) == [[True, False]]


@settings(max_examples=60, deadline=None)
@given(
    rp=st.lists(st.tuples(st.floats(0, 30), st.floats(0, 20)), min_size=1, max_size=12),
    points=st.lists(st.tuples(st.floats(0, 30), st.floats(0, 20)), max_size=12),
    readings=st.integers(0, 5),
    cell_m=st.sampled_from([0.5, 1.0, 2.5, 7.0]),
)
def test_without_a_plan_every_reading_and_point_is_in_a_cell(
    rp: list[tuple[float, float]],
    points: list[tuple[float, float]],
    readings: int,
    cell_m: float,
) -> None:
    count = np.full((len(rp), 3), readings)
    g = grid(
        plan=None,
        rp_xy=rp,
        count=count,
        kinds=["wifi", "wifi", "ble"],
        point_xy=points,
        created_s=[NOW_S] * len(points),
        cell_m=cell_m,
    )
    assert g.readings.sum() == count.sum()
    assert g.points.sum() == len(points)
    # never better than the distance to the nearest RP, nor than the best σ of the table
    assert (g.expected_error_m >= g.nearest_rp_m).all()
    assert (g.expected_error_m >= math.sqrt(2) * fix_error.DEFAULT_SIGMA_FLOOR_M).all()
