"""Zone presence: entering and leaving a zone once the fixes have stayed across its border
for the dwell time or distance, and never on a fix wobbling across it."""

from __future__ import annotations

import shapely
from hypothesis import given
from hypothesis import strategies as st

from server.positioning.plan.zone_presence import Dwell, FixPlace, Presence, follow
from server.positioning.plan.zones import Zone, ZoneIndex

# zone "shop" holds x in [10, 20], y in [0, 10] on floor 0
SHOP = Zone(0, "f0", "shop", "Shop", shapely.box(10, 0, 20, 10))
ZONES = ZoneIndex([SHOP])
DWELL = Dwell(seconds=3.0, metres=3.0)


def walk(xs: list[float], dt_ms: int = 500, floor: int = 0, y: float = 5.0) -> list[FixPlace]:
    return [FixPlace(1000 + i * dt_ms, floor, x, y) for i, x in enumerate(xs)]


def events(after: list) -> list[tuple[str, str, int, int, float | None]]:  # type: ignore[type-arg]
    return [(e.kind, e.zone.id, e.t_ms, e.since_ms, e.dwell_s) for a in after for e in a.events]


def test_walking_through_enters_once_and_leaves_once_with_the_dwell() -> None:
    # 0.5 m per 0.5 s: in at x = 10 (t = 1000 + 20 * 500), out at x = 20.5
    xs = [i * 0.5 for i in range(60)]
    state, after = follow({}, walk(xs), ZONES, DWELL)
    found = events(after)
    # in at t = 11000 (x = 10); 3 m inside (x = 13, t = 14000) confirmed
    # out at t = 21500 (x = 20.5); 3 m outside (x = 23, t = 24000) confirmed
    assert found == [("enter", "shop", 14000, 11000, None), ("exit", "shop", 24000, 21500, 10.5)]
    assert state == {}
    inside = [bool(a.inside) for a in after]
    assert inside.index(True) == 26  # x = 13
    assert inside.count(True) == 46 - 26  # out from x = 23


def test_standing_on_the_border_and_wobbling_makes_no_event() -> None:
    xs = [9.8, 10.2] * 40  # 40 s of fixes either side of the border
    state, after = follow({}, walk(xs), ZONES, DWELL)
    assert events(after) == []
    assert not any(a.inside for a in after)
    assert state["f0/shop"].inside is False  # a contrary run is pending
    assert state["f0/shop"].pending_ms >= 0


def test_one_fix_far_inside_is_not_enough_two_are() -> None:
    # a fix that jumps 5 m into the zone and back: nothing
    _, after = follow({}, walk([8.0, 15.0, 8.0, 8.0]), ZONES, DWELL)
    assert events(after) == []
    # two fixes in a row, the second 3 m past the border: in at once
    _, after = follow({}, walk([8.0, 10.5, 13.5]), ZONES, DWELL)
    assert events(after) == [("enter", "shop", 2000, 1500, None)]


def test_fixes_far_apart_but_near_the_border_do_not_leave() -> None:
    """Outside fixes 3.5 m apart, each within a metre of the border: the distance that
    counts is the one beyond the border, not between fixes."""
    state, _ = follow({}, walk([15.0] * 8), ZONES, DWELL)
    near = [FixPlace(5000, 0, 9.5, 1.0), FixPlace(5200, 0, 9.5, 4.5), FixPlace(5400, 0, 15, 5)]
    state, after = follow(state, near, ZONES, DWELL)
    assert events(after) == []
    assert state["f0/shop"].inside


def test_standing_just_inside_enters_after_the_dwell_time() -> None:
    _, after = follow({}, walk([10.5] * 10), ZONES, DWELL)
    assert events(after) == [("enter", "shop", 1000 + 6 * 500, 1000, None)]


def test_presence_carries_across_batches() -> None:
    xs = [i * 0.5 for i in range(60)]
    fixes = walk(xs)
    whole = events(follow({}, fixes, ZONES, DWELL)[1])
    state: dict[str, Presence] = {}
    parts = []
    for start in range(0, len(fixes), 7):
        state, after = follow(state, fixes[start : start + 7], ZONES, DWELL)
        parts += events(after)
    assert parts == whole


def test_a_fix_on_another_floor_is_outside() -> None:
    inside = walk([15.0] * 8)
    state, after = follow({}, inside, ZONES, DWELL)
    assert events(after)[0][0] == "enter"
    upstairs = [FixPlace(5000 + i * 500, 1, 15.0, 5.0) for i in range(8)]
    state, after = follow(state, upstairs, ZONES, DWELL)
    assert [e[0] for e in events(after)] == ["exit"]
    assert state == {}


def test_zones_gone_from_the_site_are_forgotten_without_an_event() -> None:
    state, _ = follow({}, walk([15.0] * 8), ZONES, DWELL)
    assert state["f0/shop"].inside
    state, after = follow(state, walk([15.0]), ZoneIndex([]), DWELL)
    assert state == {}
    assert events(after) == []


@given(st.lists(st.floats(9.0, 11.0), min_size=1, max_size=200))
def test_fixes_within_a_metre_of_the_border_at_two_a_second_never_flap(xs: list[float]) -> None:
    """Whatever the wobble, events alternate enter, exit, enter, ... and each run that
    confirms one lasted the dwell time (a metre of wobble never reaches the distance)."""
    _, after = follow({}, walk(xs), ZONES, DWELL)
    found = events(after)
    kinds = [e[0] for e in found]
    assert kinds == ["enter", "exit"][: len(kinds)] * (len(kinds) // 2) + (
        ["enter"] if len(kinds) % 2 else []
    )
    for _, _, t, since, _ in found:
        assert t - since >= 3000
