"""The one map builder: fold groups and walks of surveyed scans, and a map set built from
a small synthetic two-floor site (fix-error table, FAI maps, floor graphs with moves
learned from the walks, magnetic grids), deterministic for a seed."""

from __future__ import annotations

from collections.abc import Hashable, Sequence

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.typing import NDArray

from server.positioning.engines.shared.site_maps import FloorRef
from server.positioning.mapping.map_set import (
    FAI,
    FIX_ERROR,
    GRAPHS,
    MAGNETIC,
    PARTS,
    FloorField,
    KeyedScan,
    SiteRecords,
    SurveyedScans,
    build_map_set,
    grid_scans,
)
from server.positioning.plan.navigation_graph import FloorGraph, learn
from server.positioning.radio import fix_error

# ---------------------------------------------------------------- a synthetic site

FLOORS = (FloorRef("b", "f0", 0), FloorRef("b", "f1", 1))
WIDTH_M, DEPTH_M = 40.0, 12.0
# eight APs per floor; a floor hears the other's 18 dB weaker
AP_XY = np.array(
    [[0, 0], [20, 0], [40, 0], [0, 12], [20, 12], [40, 12], [10, 6], [30, 6]], dtype=np.float64
)
# corridors on vertices of the 1 m grid, so a walk's positions snap to one vertex each
CORRIDORS_Y = (1.5, 5.5, 9.5)
CROSS_X = 20.5

Leg = tuple[int, tuple[float, float], tuple[float, float]]  # floor, start, end


def _walks() -> list[tuple[str, str | None, list[Leg]]]:
    """Twelve walks (name, route, legs): on each floor east along the three corridors,
    back west along the middle one (the same route as the way east) and north across
    them; one walk takes the stairs from floor 0 to floor 1."""
    walks: list[tuple[str, str | None, list[Leg]]] = []
    for floor in (0, 1):
        for y in CORRIDORS_Y:
            walks.append((f"f{floor}-y{y}", f"f{floor}-y{y}", [(floor, (0.5, y), (39.5, y))]))
        mid = CORRIDORS_Y[1]
        walks.append((f"f{floor}-back", f"f{floor}-y{mid}", [(floor, (39.5, mid), (0.5, mid))]))
        walks.append((f"f{floor}-cross", None, [(floor, (CROSS_X, 0.5), (CROSS_X, 11.5))]))
    walks.append(("stairs", None, [(0, (0.5, 9.5), (9.5, 9.5)), (1, (9.5, 9.5), (0.5, 9.5))]))
    return walks


def _readings(xy: NDArray[np.float64], floor: int, rng: np.random.Generator) -> KeyedScan:
    """Log-distance RSS with 3 dB of noise; what is below -95 dBm is not heard."""
    out: list[tuple[str, float]] = []
    for ap_floor in (0, 1):
        d = np.maximum(np.hypot(*(AP_XY - xy).T), 1.0)
        rss = -35.0 - 25.0 * np.log10(d) - 18.0 * abs(ap_floor - floor)
        rss = rss + rng.normal(0.0, 3.0, d.size)
        out += [
            (f"wifi:02:00:00:00:{ap_floor:02x}:{j:02x}", float(v))
            for j, v in enumerate(rss)
            if v > -95.0
        ]
    return out


def _site_scans(seed: int = 0, *, labelled: bool = True) -> SurveyedScans:
    """A scan every metre of every walk, a second apart (unlabelled: the same scans as
    points surveyed on their own)."""
    rng = np.random.default_rng(seed)
    xy: list[NDArray[np.float64]] = []
    floor: list[int] = []
    t_ms: list[int] = []
    walk: list[str | None] = []
    route: list[str | None] = []
    readings: list[KeyedScan] = []
    for name, route_name, legs in _walks():
        for leg_floor, start, end in legs:
            a, b = np.array(start), np.array(end)
            for s in np.linspace(0.0, 1.0, round(float(np.linalg.norm(b - a))) + 1):
                here = a + s * (b - a)
                xy.append(here)
                floor.append(leg_floor)
                t_ms.append(1000 * len(t_ms))
                walk.append(name)
                route.append(route_name)
                readings.append(_readings(here, leg_floor, rng))
    if not labelled:
        return SurveyedScans.of(np.array(xy), floor, readings, t_ms=t_ms)
    return SurveyedScans.of(np.array(xy), floor, readings, t_ms=t_ms, walk=walk, route=route)


@pytest.fixture(scope="module")
def records() -> SiteRecords:
    return SiteRecords(FLOORS, _site_scans())


def _partition(groups: NDArray[np.int64]) -> set[frozenset[int]]:
    """Which scans share a fold group (the numbers themselves are the builder's)."""
    return {frozenset(np.flatnonzero(groups == g).tolist()) for g in np.unique(groups)}


def _scans(
    walk: Sequence[Hashable | None], route: Sequence[Hashable | None] | None = None
) -> SurveyedScans:
    n = len(walk)
    xy = np.column_stack([np.arange(n, dtype=np.float64), np.zeros(n)])
    return SurveyedScans.of(xy, [0] * n, [[("wifi:a", -50.0)]] * n, walk=walk, route=route)


# ---------------------------------------------------------------- fold groups


def test_a_route_beats_a_walk_and_a_walk_beats_the_scan_alone() -> None:
    scans = _scans(
        walk=["a", "a", "b", None, "c", None, "c"],
        route=["R", None, "R", None, None, None, None],
    )
    # 0 and 2 share route R although their walks differ; 1 is what is left of walk a;
    # 4 and 6 share walk c; the unlabelled 3 and 5 are each alone
    assert _partition(scans.groups()) == {
        frozenset({0, 2}),
        frozenset({1}),
        frozenset({3}),
        frozenset({4, 6}),
        frozenset({5}),
    }


def test_unlabelled_scans_are_each_a_group_of_their_own() -> None:
    scans = _scans(walk=[None] * 5)
    assert np.unique(scans.groups()).size == 5
    labelled = _scans(walk=[None, 0, None, 0, None], route=[None, None, None, None, 7])
    assert _partition(labelled.groups()) == {
        frozenset({0}),
        frozenset({1, 3}),
        frozenset({2}),
        frozenset({4}),
    }


def test_labels_are_numbered_by_first_appearance_whatever_their_type() -> None:
    named = _scans(walk=["w2", "w1", "w2", None, "w3"], route=["r", None, "r", None, None])
    numbered = _scans(walk=[20, 10, 20, None, 30], route=[(1, 2), None, (1, 2), None, None])
    np.testing.assert_array_equal(named.walk, [0, 1, 0, -1, 2])
    np.testing.assert_array_equal(named.route, [0, -1, 0, -1, -1])
    for name in ("walk", "route"):
        np.testing.assert_array_equal(getattr(named, name), getattr(numbered, name))
    np.testing.assert_array_equal(named.groups(), numbered.groups())


LABELS = st.lists(st.one_of(st.none(), st.integers(0, 3)), min_size=1, max_size=30)


@given(walk=LABELS, route=LABELS)
def test_groups_follow_the_rule_under_any_renaming(
    walk: list[int | None], route: list[int | None]
) -> None:
    n = min(len(walk), len(route))
    walk, route = walk[:n], route[:n]
    scans = _scans(walk, route)
    # the rule, written out: the route, else the walk, else the scan alone
    key = [
        ("route", r) if r is not None else ("walk", w) if w is not None else ("alone", i)
        for i, (w, r) in enumerate(zip(walk, route, strict=True))
    ]
    expected = {frozenset(i for i in range(n) if key[i] == k) for k in key}
    assert _partition(scans.groups()) == expected
    # other labels for the same walks and routes, of another type: the same scans
    renamed = _scans(
        [None if w is None else f"walk {9 - w}" for w in walk],
        [None if r is None else ("route", r * 7) for r in route],
    )
    np.testing.assert_array_equal(renamed.walk, scans.walk)
    np.testing.assert_array_equal(renamed.route, scans.route)
    np.testing.assert_array_equal(renamed.groups(), scans.groups())


# ---------------------------------------------------------------- walks


def test_walks_are_in_time_order_cut_at_floor_changes_without_lone_scans() -> None:
    # walk "up" recorded out of order: by time it is (0, 0) (1, 0) on floor 0, (2, 0)
    # (3, 0) on floor 1, (4, 0) back on floor 0; "other" stays on floor 1; the points
    # without a walk are in none
    rows = [
        # x, floor, t_ms, walk
        (3.0, 1, 4000, "up"),
        (9.0, 0, 500, None),
        (0.0, 0, 1000, "up"),
        (7.0, 1, 9000, "other"),
        (4.0, 0, 5000, "up"),
        (2.0, 1, 3000, "up"),
        (8.0, 1, 8000, "other"),
        (1.0, 0, 2000, "up"),
        (9.5, 1, 2500, None),
    ]
    xy = [(x, 0.0) for x, *_ in rows]
    scans = SurveyedScans.of(
        xy,
        [f for _, f, _, _ in rows],
        [[("wifi:a", -50.0)]] * len(rows),
        t_ms=[t for *_, t, _ in rows],
        walk=[w for *_, w in rows],
    )
    walks = scans.walks()
    assert sorted(walks) == [0, 1]
    got = {f: [w[:, 0].tolist() for w in walks[f]] for f in walks}
    assert got == {0: [[0.0, 1.0], [4.0]], 1: [[2.0, 3.0], [8.0, 7.0]]}


def test_scans_of_equal_time_keep_their_order_and_unknown_times_count_as_zero() -> None:
    scans = SurveyedScans.of(
        [(0.0, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0)],
        [0, 0, 0, 0],
        [[("wifi:a", -50.0)]] * 4,
        t_ms=[5, None, 5, 0],
        walk=["w"] * 4,
    )
    np.testing.assert_array_equal(scans.t_ms, [5, 0, 5, 0])
    (walk,) = scans.walks()[0]
    assert walk[:, 0].tolist() == [1.0, 3.0, 0.0, 2.0]


# ---------------------------------------------------------------- the map set


def test_the_fix_error_table_is_learned_from_held_out_routes(records: SiteRecords) -> None:
    maps = build_map_set(records, parts={FIX_ERROR}, seed=0)
    model = maps.fix_error
    assert model.error_68_m != fix_error.DEFAULT_ERROR_68_M
    assert 1.0 < model.error_68_m < 10.0  # metres off, on a 40 m x 12 m floor
    assert set(model.sigma_m) == {"wifi"}
    n_fixes = sum(model.counts["wifi"])
    assert fix_error.MIN_BIN_COUNT <= n_fixes <= len(records.scans)
    # the APs of both floors are heard: 16 matched emitters are worth more than the
    # default says
    assert model.sigma("wifi", 16) < fix_error.default_sigma_m(16)
    # without routes every scan is held out alone, and the scans of its own walk a metre
    # away locate it: the same scans look far better than held out route by route
    alone = build_map_set(SiteRecords(FLOORS, _site_scans(labelled=False)), parts={FIX_ERROR})
    assert alone.fix_error.error_68_m < 0.75 * model.error_68_m


def test_the_map_set_is_the_same_for_the_same_seed(records: SiteRecords) -> None:
    first = build_map_set(records, parts={FIX_ERROR}, seed=3)
    again = build_map_set(records, parts={FIX_ERROR}, seed=3)
    other = build_map_set(records, parts={FIX_ERROR}, seed=4)
    assert first.fix_error == again.fix_error
    # the seed deals the routes into folds: another deal, other held-out errors
    assert other.fix_error != first.fix_error


def test_parts_choose_what_is_built(records: SiteRecords) -> None:
    radio = grid_scans(records.scans)
    assert radio is not None
    bare = build_map_set(records, parts=(), version="v7")
    assert bare.version == "v7"
    assert bare.radio is not None
    np.testing.assert_array_equal(bare.radio.rp_xy, radio.rp_xy)
    np.testing.assert_array_equal(bare.radio.mean_dbm, radio.mean_dbm)
    assert bare.fix_error == fix_error.DEFAULT
    assert bare.fai is None
    assert bare.graphs == ()
    assert bare.magnetic is None
    # the caller's radio map is the one used
    given_radio = build_map_set(records, parts={FAI}, radio=radio)
    assert given_radio.radio is radio
    assert given_radio.fai is not None
    assert given_radio.fai.dsf_m.shape == (radio.rp_xy.shape[0],)
    assert given_radio.fai.emitter_xy.shape == (len(radio.emitters), 2)
    assert given_radio.fix_error == fix_error.DEFAULT
    assert given_radio.graphs == ()


@pytest.mark.parametrize("parts", [{"fix_errors"}, {FAI, "radio"}, PARTS | {"nowhere"}])
def test_an_unknown_part_is_refused(records: SiteRecords, parts: set[str]) -> None:
    (unknown,) = set(parts) - PARTS
    with pytest.raises(ValueError, match=unknown):
        build_map_set(records, parts=parts)


def _moves_from(graph: FloorGraph, xy: tuple[float, float]) -> dict[tuple[float, float], float]:
    """The chain's move probabilities out of the vertex at ``xy``, by where they go."""
    v = graph.nearest(xy)
    assert np.allclose(graph.xy[v], xy)
    links = slice(graph.indptr[v], graph.indptr[v + 1])
    return {
        (float(x), float(y)): float(p)
        for (x, y), p in zip(graph.xy[graph.indices[links]], graph.move_p[links], strict=True)
    }


def test_floor_graphs_learn_their_moves_from_the_walks(records: SiteRecords) -> None:
    walked = build_map_set(records, parts={GRAPHS})
    unwalked = build_map_set(SiteRecords(FLOORS, _site_scans(labelled=False)), parts={GRAPHS})
    walks = records.scans.walks()
    assert len(walked.graphs) == len(unwalked.graphs) == 2
    for floor, (graph, uniform) in enumerate(zip(walked.graphs, unwalked.graphs, strict=True)):
        assert graph is not None
        assert uniform is not None
        np.testing.assert_array_equal(graph.xy, uniform.xy)
        np.testing.assert_array_equal(graph.indices, uniform.indices)
        np.testing.assert_array_equal(graph.stay_p, uniform.stay_p)
        assert not np.allclose(graph.move_p, uniform.move_p)
        # exactly eq 15 counted over the floor's walks
        np.testing.assert_allclose(graph.move_p, learn(uniform, walks[floor]).move_p)
        rows = np.asarray(graph.transition_matrix().sum(axis=1)).ravel()
        np.testing.assert_allclose(rows, 1.0)
    # floor 0's south corridor is walked east only: from its middle, east is the likeliest
    # move; before any walk every move is as likely as another
    here = (10.5, CORRIDORS_Y[0])
    graph, uniform = walked.graphs[0], unwalked.graphs[0]
    assert graph is not None
    assert uniform is not None
    moves = _moves_from(graph, here)
    assert max(moves, key=lambda k: moves[k]) == (11.5, CORRIDORS_Y[0])
    assert len(set(_moves_from(uniform, here).values())) == 1


def test_magnetic_grids_cover_the_floors_with_samples(records: SiteRecords) -> None:
    rng = np.random.default_rng(5)
    xy = rng.uniform([0.0, 0.0], [WIDTH_M, DEPTH_M], (200, 2))
    field = {1: FloorField(xy, 45.0 + rng.normal(0.0, 2.0, 200), (0.0, 0.0, WIDTH_M, DEPTH_M))}
    with_field = SiteRecords(FLOORS, records.scans, field=field)
    maps = build_map_set(with_field, parts={MAGNETIC}, version="v3")
    assert maps.magnetic is not None
    assert maps.magnetic.version == "v3"
    assert maps.magnetic.grids[0] is None
    assert maps.magnetic.grids[1] is not None
    assert build_map_set(records, parts={MAGNETIC}).magnetic is None


def test_buildings_fai_fits_are_merged_by_emitter_key(records: SiteRecords) -> None:
    from dataclasses import replace as with_

    from server.positioning.mapping.map_set import merged_fai
    from server.positioning.radio.accuracy_indicators import FaiParams, spreads

    maps = build_map_set(records, parts={FAI})
    assert maps.radio is not None
    assert maps.fai is not None
    keys = maps.radio.emitters
    half = len(keys) // 2
    # two "buildings", each knowing half the columns, listed in reverse order
    parts = [
        (
            keys[:half][::-1],
            with_(
                maps.fai,
                emitter_xy=maps.fai.emitter_xy[:half][::-1],
                p0_dbm=maps.fai.p0_dbm[:half][::-1],
                exponent=maps.fai.exponent[:half][::-1],
            ),
        ),
        (
            keys[half:],
            with_(
                maps.fai,
                emitter_xy=maps.fai.emitter_xy[half:],
                p0_dbm=maps.fai.p0_dbm[half:],
                exponent=maps.fai.exponent[half:],
            ),
        ),
    ]
    merged = merged_fai(maps.radio, parts)
    assert merged is not None
    for name in ("emitter_xy", "p0_dbm", "exponent"):
        np.testing.assert_array_equal(getattr(merged, name), getattr(maps.fai, name))
    params = FaiParams()
    np.testing.assert_array_equal(
        merged.dsf_m, spreads(maps.radio, params.kappa_d, params.min_sd_db)
    )
    assert merged_fai(maps.radio, []) is None


def test_the_site_keeps_the_table_learned_from_most_fixes(records: SiteRecords) -> None:
    from server.positioning.mapping.map_set import most_learned

    learned = build_map_set(records, parts={FIX_ERROR}).fix_error
    assert most_learned([]) is fix_error.DEFAULT
    assert most_learned([fix_error.DEFAULT, learned]) is learned
    assert most_learned([learned, fix_error.DEFAULT]) is learned
