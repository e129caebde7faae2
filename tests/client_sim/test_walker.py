"""Walker: deterministic, on walkable paths, and its steps integrate back to its truth."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from client_sim.building import count_crossings
from client_sim.seeding import sequence
from client_sim.walker import TimedEvent, Truth, TruthTrack, Walker, WalkerParams
from client_sim.world import synthesize_world

WORLD = synthesize_world(0)
T0 = 1_700_000_000_000
NOISELESS = WalkerParams(length_noise_sd_m=0.0, heading_noise_sd_rad=0.0, heading_bias_sd_rad=0.0)


def walk(
    n_events: int, seed: int = 0, level: int = 0, params: WalkerParams | None = None
) -> tuple[Walker, list[TimedEvent]]:
    walker = Walker(WORLD, level, sequence(seed, "walker", 0), T0, params)
    return walker, list(itertools.islice(walker.events(), n_events))


def steps_of(events: list[TimedEvent]) -> list[TimedEvent]:
    return [e for e in events if e.event["type"] == "step"]


def true_steps(walker: Walker, events: list[TimedEvent]) -> tuple[np.ndarray, np.ndarray]:
    """True step vectors and where each step ended, from the start."""
    ends = np.array([(e.truth.x_m, e.truth.y_m) for e in steps_of(events)])
    return np.diff(np.vstack([walker.start_xy, ends]), axis=0), ends


def reported_steps(events: list[TimedEvent]) -> np.ndarray:
    return np.array(
        [
            (
                e.event["length_m"] * math.sin(e.event["heading_rad"]),
                e.event["length_m"] * math.cos(e.event["heading_rad"]),
            )
            for e in steps_of(events)
        ]
    )


def test_same_seed_same_walk_and_events_restart() -> None:
    walker, a = walk(500)
    _, b = walk(500)
    assert [e.event for e in a] == [e.event for e in b]
    again = list(itertools.islice(walker.events(), 500))
    assert [e.event for e in again] == [e.event for e in a]
    _, other = walk(500, seed=1)
    assert [e.event for e in other] != [e.event for e in a]


def test_events_are_timed_on_the_phone_clock_in_order() -> None:
    walker, events = walk(2000, level=1)
    t = [e.event["t"] for e in events]
    assert t == sorted(t)
    assert all(e.event["t"] == T0 + round(1000 * e.sim_s) == e.truth.t for e in events)
    assert all(e.truth.level == 1 for e in events)
    kinds = [e.event["type"] for e in events]
    assert set(kinds) == {"step", "mag", "wifi", "ble"}
    # a magnetometer reading at every step
    for step, mag in itertools.pairwise(events):
        if step.event["type"] == "step":
            assert mag.event["type"] == "mag"
            assert mag.event["t"] == step.event["t"]
            assert len(mag.event["field_ut"]) == 3
    wifi_s = np.array([e.sim_s for e in events if e.event["type"] == "wifi"])
    assert wifi_s[0] <= 1.0
    assert np.all((np.diff(wifi_s) >= 2.0) & (np.diff(wifi_s) <= 4.0))
    ble_s = np.array([e.sim_s for e in events if e.event["type"] == "ble"])
    assert np.all((np.diff(ble_s) >= 4.0) & (np.diff(ble_s) <= 10.0))
    step_s = np.array([e.sim_s for e in steps_of(events)])
    assert 0.55 <= walker.step_period_s <= 0.65
    assert np.mean(np.diff(step_s)) == pytest.approx(walker.step_period_s, abs=0.01)
    for e in steps_of(events):
        assert 0 < e.event["length_m"] <= 3.0
        assert -math.pi < e.event["heading_rad"] <= math.pi


def test_walker_stays_on_walkable_paths() -> None:
    for seed, level in ((0, 0), (1, 1), (2, 0)):
        walker, events = walk(3000, seed=seed, level=level)
        floor = WORLD.building.floor(level)
        xy = np.array([(e.truth.x_m, e.truth.y_m) for e in events])
        path = np.vstack([walker.start_xy, xy])
        assert np.all(floor.contains(path))
        assert count_crossings(path[:-1], path[1:], floor.walls).sum() == 0
        # never further from a graph edge than the shortest step
        a, b = floor.nodes[floor.edges[:, 0]], floor.nodes[floor.edges[:, 1]]
        ab = b - a
        u = np.clip(
            np.einsum("ned,ed->ne", path[:, None, :] - a[None], ab) / np.sum(ab * ab, axis=1),
            0.0,
            1.0,
        )
        nearest = a[None] + u[..., None] * ab[None]
        off_graph = np.min(np.linalg.norm(path[:, None, :] - nearest, axis=-1), axis=1)
        assert off_graph.max() <= WalkerParams().min_step_m + 1e-9
        # it goes places: several rooms and corridors on the way
        visited = [
            r
            for r in floor.walkable
            if np.any(
                (path[:, 0] > r.x0)
                & (path[:, 0] < r.x1)
                & (path[:, 1] > r.y0)
                & (path[:, 1] < r.y1)
            )
        ]
        assert {r.use for r in visited} == {"room", "corridor"}
        assert len(visited) > 5


def test_true_steps_have_the_walkers_stride() -> None:
    walker, events = walk(3000)
    vectors, _ = true_steps(walker, events)
    lengths = np.hypot(vectors[:, 0], vectors[:, 1])
    assert 0.65 <= walker.stride_m <= 0.75
    assert lengths.min() >= WalkerParams().min_step_m - 1e-9
    assert lengths.max() <= walker.stride_m + 5 * WalkerParams().step_length_sd_m
    assert np.median(lengths) == pytest.approx(walker.stride_m, abs=0.02)  # turns shorten a few


def test_noiseless_steps_integrate_back_to_the_truth() -> None:
    walker, events = walk(3000, params=NOISELESS)
    _, ends = true_steps(walker, events)
    track = np.asarray(walker.start_xy) + np.cumsum(reported_steps(events), axis=0)
    assert np.max(np.linalg.norm(track - ends, axis=1)) < 0.05  # wire rounding only


def test_noisy_steps_integrate_back_within_the_noise() -> None:
    p = WalkerParams()
    walker, events = walk(6000)
    true_vectors, ends = true_steps(walker, events)
    steps = steps_of(events)
    true_length = np.hypot(true_vectors[:, 0], true_vectors[:, 1])
    true_heading = np.arctan2(true_vectors[:, 0], true_vectors[:, 1])
    length_error = np.array([e.event["length_m"] for e in steps]) - true_length
    heading_error = np.angle(
        np.exp(1j * (np.array([e.event["heading_rad"] for e in steps]) - true_heading))
    )
    assert np.mean(length_error) == pytest.approx(0.0, abs=0.01)
    assert np.std(length_error) == pytest.approx(p.length_noise_sd_m, rel=0.15)
    # white noise on top of a slow bias: step-to-step differences see the white part only
    assert np.std(np.diff(heading_error)) / math.sqrt(2) == pytest.approx(
        p.heading_noise_sd_rad, rel=0.15
    )
    assert np.std(heading_error) < math.hypot(p.heading_noise_sd_rad, 3 * p.heading_bias_sd_rad)
    # dead reckoning drifts, but only as fast as those errors allow: 100 steps, ~70 m
    track = np.asarray(walker.start_xy) + np.cumsum(reported_steps(events), axis=0)
    drift = np.linalg.norm(track[99] - ends[99])
    assert drift < 100 * 0.7 * 3 * p.heading_bias_sd_rad + 3 * math.sqrt(100) * 0.05


def test_truth_track_interpolates_between_truths() -> None:
    track = TruthTrack()
    with pytest.raises(LookupError):
        track.at(0)
    track.add(Truth(1000, 0.0, 0.0, 0, 0.0))
    track.add(Truth(2000, 10.0, 4.0, 0, 0.0))
    track.add(Truth(3000, 10.0, 4.0, 1, 0.0))
    assert track.at(1500) == (5.0, 2.0, 0)
    assert track.at(500) == (0.0, 0.0, 0)  # clamped
    assert track.at(9000) == (10.0, 4.0, 1)
    assert track.at(3000)[2] == 1
    assert track.at(2999)[2] == 0
    assert len(track) == 3
    with pytest.raises(ValueError, match="time order"):
        track.add(Truth(2500, 0.0, 0.0, 0, 0.0))
