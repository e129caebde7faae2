"""The capacity search of ``indoorpos bench load`` (the measuring itself is a benchmark)."""

from __future__ import annotations

import pytest

from lab.load_bench import Level, _api_cpus, find_capacity


def _level(users: int, held: bool) -> Level:
    return Level(
        processes=1, users=users, held=held, p50_ms=1.0, p95_ms=2.0, p99_ms=3.0, errors=0,
        batches=1, steps=1, duration_s=1.0, steps_per_s=1.0, server_cpu_s=0.0,
        server_cpu_us_per_step=None, client_cpu_s=0.0, mean_error_m=None, first_error=None,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("capacity", "start", "users_max"), [(137, 50, 3000), (20, 50, 3000), (3000, 50, 3000)]
)
def test_finds_the_largest_count_held_within_the_resolution(
    capacity: int, start: int, users_max: int
) -> None:
    tried: list[int] = []

    def hold(users: int) -> Level:
        tried.append(users)
        return _level(users, users <= capacity)

    levels = find_capacity(hold, start, users_max)
    best = max(level.users for level in levels if level.held)
    assert best <= capacity
    assert best >= capacity * 0.9 or capacity - best <= 1
    assert [level.users for level in levels] == tried
    assert len(tried) == len(set(tried))  # no count is walked twice
    assert len(tried) <= 16


def test_nothing_held_ends_at_one_user() -> None:
    levels = find_capacity(lambda users: _level(users, False), 50, 100)
    assert levels[-1].users == 1
    assert not any(level.held for level in levels)


def test_the_api_gets_a_cpu_per_process_and_the_simulator_keeps_one() -> None:
    assert _api_cpus([0], 1) is None  # one CPU: nothing to pin
    assert _api_cpus([0, 1], 1) == {0}
    assert _api_cpus([0, 1], 2) == {0}  # two CPUs: both processes share the api's
    assert _api_cpus([0, 1, 2, 3], 2) == {0, 1}
