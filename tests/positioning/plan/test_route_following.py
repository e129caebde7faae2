"""Navigation along a route, fix by fix: progress and the next step, the instruction
withheld while the fix is less sure than the turn is near, re-routing only after the
hysteresis, floor changes and one arrival."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.plan.route_following import (
    FixAt,
    Guide,
    Progress,
    Settings,
    follow,
    place,
)
from server.positioning.plan.route_steps import route_steps
from server.positioning.plan.routes import FloorChange, Leg, Route

# east 20 m, then north 10 m on floor 0; lift to floor 1; east 5 m
ROUTE = Route(
    legs=(
        Leg(0, np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 10.0]])),
        Leg(1, np.array([[20.0, 10.0], [25.0, 10.0]])),
    ),
    changes=(FloorChange("elevator", "Lift", 0, 1, 38.0),),
)


def _guide(route: Route = ROUTE) -> Guide:
    steps = route_steps(route, [0, 1])
    return Guide(
        floors=tuple(leg.floor for leg in route.legs),
        legs=tuple(leg.xy for leg in route.legs),
        change_s=tuple(c.seconds for c in route.changes),
        steps=tuple(steps),
        walk_speed_m_s=1.2,
        change_kinds=tuple(c.kind for c in route.changes),
    )


def _never(_: FixAt) -> Guide | None:
    raise AssertionError("re-routed")


def test_the_steps_of_the_route() -> None:
    kinds = [s.kind for s in _guide().steps]
    assert kinds == ["start", "left", "lift_up", "straight", "arrive"]
    assert [s.along_m for s in _guide().steps] == [0.0, 20.0, 30.0, 30.0, 35.0]


def test_progress_and_the_next_instruction() -> None:
    guide, settings = _guide(), Settings()
    report = follow(guide, Progress(), FixAt(0, 0, 12.0, 1.0, 2.0), settings, _never)
    assert report.on_route
    assert report.off_route_m is not None
    assert abs(report.off_route_m - 1.0) < 1e-9
    assert report.progress.along_m == 12.0
    assert report.next is not None
    assert report.next.kind == "left"
    assert report.distance_to_next_m == 8.0
    assert not report.withheld
    assert report.snapped == (0, 12.0, 0.0)
    assert abs(report.remaining_m - 23.0) < 1e-9
    assert abs(report.remaining_s - (23.0 / 1.2 + 38.0)) < 1e-9
    # a fix less sure (68 %: 9 m) than the turn is near (8 m): "continue"
    unsure = follow(guide, Progress(), FixAt(0, 0, 12.0, 1.0, 9.0), settings, _never)
    assert unsure.withheld


@given(st.floats(-4.9, 4.9), st.integers(1, 20))
def test_one_wild_fix_or_a_wobble_does_not_reroute(offset: float, n: int) -> None:
    guide, settings = _guide(), Settings(off_route_m=5.0, reroute_after_s=4.0, reroute_fixes=3)
    progress = Progress()
    for k in range(n):
        wild = 30.0 if k % 3 == 1 else offset  # every third fix far off, the others near
        report = follow(guide, progress, FixAt(1000 * k, 0, 0.5 * k, wild), settings, _never)
        progress = report.progress
    assert progress.reroutes == 0


def test_a_walk_off_the_route_reroutes_once_after_the_hysteresis() -> None:
    guide, settings = _guide(), Settings(off_route_m=5.0, reroute_after_s=4.0, reroute_fixes=3)
    fresh = _guide(Route((Leg(0, np.array([[5.0, -10.0], [20.0, 10.0]])),), ()))
    calls: list[FixAt] = []

    def reroute(fix: FixAt) -> Guide:
        calls.append(fix)
        return fresh

    progress, events = Progress(), []
    for k in range(10):  # walks south, away from the route, 1.5 m a second
        report = follow(
            guide, progress, FixAt(1000 * k, 0, 5.0, -float(k) * 1.5), settings, reroute
        )
        progress = report.progress
        events += [e.kind for e in report.events]
        guide = report.guide
    assert events == ["rerouted"]
    assert len(calls) == 1
    assert calls[0].t_ms == 8000
    assert progress.reroutes == 1


def test_a_floor_change_then_one_arrival() -> None:
    guide, settings = _guide(), Settings(arrival_m=1.0)
    progress, events = Progress(), []
    walk = [(0, 10.0, 0.0), (0, 20.0, 5.0), (0, 20.0, 10.0), (1, 21.0, 10.0), (1, 24.5, 10.0),
            (1, 25.0, 10.0)]  # fmt: skip
    for k, (floor, x, y) in enumerate(walk):
        report = follow(guide, progress, FixAt(1000 * k, floor, x, y, 0.5), settings, _never)
        progress = report.progress
        events += [e.kind for e in report.events]
    assert events == ["floor_change", "arrived"]
    assert progress.arrived
    assert progress.leg == 1
    assert report.next is None
    assert report.remaining_m == 0.0


def test_place_on_a_polyline() -> None:
    gap, along, at = place(np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]]), (12.0, 4.0))
    assert (gap, along, at.tolist()) == (2.0, 14.0, [10.0, 4.0])


def test_a_fix_far_off_the_route_past_its_end_has_not_arrived() -> None:
    guide, settings = _guide(), Settings(arrival_m=1.0)
    progress = Progress(leg=1, along_m=31.0, step=3)
    report = follow(guide, progress, FixAt(0, 1, 45.0, 10.0, 1.0), settings, _never)
    assert not report.progress.arrived  # 20 m beyond the end: clipped to it, not there
    report = follow(guide, progress, FixAt(0, 1, 25.0, 30.0, 1.0), settings, _never)
    assert not report.progress.arrived  # 20 m beside the end


def test_two_legs_on_one_floor_are_followed_in_turn() -> None:
    """A way through on one floor (a traversal): the second leg is taken up where the
    walker is nearer it, and the walk arrives without a re-route."""
    route = Route(
        legs=(
            Leg(0, np.array([[0.0, 0.0], [10.0, 0.0]])),
            Leg(0, np.array([[10.0, 5.0], [20.0, 5.0]])),
        ),
        changes=(FloorChange("traversal", None, 0, 0, 5.0),),
    )
    guide, settings = _guide(route), Settings(off_route_m=2.0, arrival_m=1.0)
    progress, events = Progress(), []
    for k, (x, y) in enumerate([(2, 0), (6, 0), (10, 0), (12, 5), (16, 5), (20, 5)]):
        report = follow(guide, progress, FixAt(1000 * k, 0, x, y, 0.5), settings, _never)
        assert report.on_route
        progress = report.progress
        events += [e.kind for e in report.events]
    assert events == ["arrived"]  # no floor change on one floor


def test_a_floor_change_says_where_from_and_to_and_how() -> None:
    report = follow(_guide(), Progress(along_m=29.0, step=1), FixAt(0, 1, 20.5, 10.0, 1.0),
                    Settings(), _never)  # fmt: skip
    assert [(e.kind, e.detail) for e in report.events] == [
        ("floor_change", {"from_floor": 0, "to_floor": 1, "kind": "elevator"})
    ]


def test_a_failed_search_waits_for_another_run_before_the_next() -> None:
    guide, settings = _guide(), Settings(off_route_m=3.0, reroute_after_s=2.0, reroute_fixes=2)
    calls: list[int] = []

    def nothing(fix: FixAt) -> Guide | None:
        calls.append(fix.t_ms)
        return None

    progress = Progress()
    for k in range(7):  # 10 m south of the route, a fix a second
        progress = follow(
            guide, progress, FixAt(1000 * k, 0, 5.0, -10.0), settings, nothing
        ).progress
    assert calls == [2000, 5000]  # each after a run of its own (3 s to 5 s), not every fix


def test_a_reroute_from_off_walkable_space_is_not_repeated_for_it() -> None:
    """The new route starts where the fix snapped to, 8 m away: the fix standing there
    is on the new route as far as that."""
    guide, settings = _guide(), Settings(off_route_m=3.0, reroute_after_s=2.0, reroute_fixes=2)
    fresh = _guide(Route((Leg(0, np.array([[5.0, -2.0], [20.0, -2.0]])),), ()))
    calls: list[int] = []

    def snapped(fix: FixAt) -> Guide:
        calls.append(fix.t_ms)
        return fresh

    progress = Progress()
    for k in range(10):  # standing 10 m south of the old route, 8 m of the new one
        report = follow(guide, progress, FixAt(1000 * k, 0, 5.0, -10.0), settings, snapped)
        progress, guide = report.progress, report.guide
    assert calls == [2000]
