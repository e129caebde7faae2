"""The navigation benchmark runs the batch path of an embedded service and reports what it
says, with tiny settings (no timing is asserted: the figures are in the bench's own
output)."""

from __future__ import annotations

import math
from typing import Any

import pytest

from lab.navigation_bench import TARGET_PCT, navigation_bench
from server.services.batches import SNAPSHOT_EVERY

CPU = (
    "server_cpu_us_plain", "server_cpu_us_navigating", "overhead_us", "overhead_pct",
    "process_cpu_us_plain", "process_cpu_us_navigating", "process_overhead_us",
    "process_overhead_pct",
)  # fmt: skip
BYTES = (
    "navigation_state_bytes", "fix_navigation_bytes", "answer_bytes_added",
    "log_entry_bytes_plain", "log_entry_bytes_added", "snapshot_bytes_plain",
    "snapshot_bytes_added", "store_bytes_added",
)  # fmt: skip


@pytest.fixture(scope="module")
def result() -> dict[str, Any]:
    return navigation_bench(sessions=2, batches=3, blocks=4, engines=("wknn",), levels=(0,), seed=1)


@pytest.fixture(scope="module")
def wknn(result: dict[str, Any]) -> dict[str, Any]:
    figures: dict[str, Any] = result["engines"][0]
    return figures


def test_reports_every_figure(result: dict[str, Any], wknn: dict[str, Any]) -> None:
    assert {k: v for k, v in result.items() if k != "engines"} == {
        "sessions": 2, "batches": 3, "blocks": 4, "geo": True, "levels": [0], "seed": 1,
        "target_pct": TARGET_PCT,
    }  # fmt: skip
    assert [f["engine"] for f in result["engines"]] == ["wknn"]
    assert list(wknn) == [
        "engine", "batches_per_kind", *CPU, "overhead_us_by_block", "navigate_cpu_us",
        "overhead_outside_navigate_us", "target_met", "fixes_per_batch_plain",
        "fixes_per_batch_navigating", "navigating_batches_without_navigation",
        "off_route_share", "reroutes", "arrivals", "steps_without_path", *BYTES,
        "navigate_us_per_fix", "profile", "profile_cumulative",
    ]  # fmt: skip


def test_cpu_figures_are_sane(wknn: dict[str, Any]) -> None:
    assert wknn["batches_per_kind"] == 4 * 3  # in each block, one session's 3 batches
    for name in CPU:
        assert math.isfinite(wknn[name])
    assert wknn["server_cpu_us_plain"] > 0
    assert wknn["process_cpu_us_plain"] >= wknn["server_cpu_us_plain"] * 0.5
    plain, navigating = wknn["server_cpu_us_plain"], wknn["server_cpu_us_navigating"]
    assert wknn["overhead_us"] == pytest.approx(navigating - plain)
    assert wknn["overhead_pct"] == pytest.approx(100 * (navigating - plain) / plain)
    assert wknn["target_met"] is (wknn["overhead_pct"] <= TARGET_PCT)
    assert len(wknn["overhead_us_by_block"]) == 4
    assert wknn["navigate_cpu_us"] > 0  # navigate's own, where the service calls it
    outside = wknn["overhead_us"] - wknn["navigate_cpu_us"]
    assert wknn["overhead_outside_navigate_us"] == pytest.approx(outside)


def test_the_walks_navigated_as_meant(wknn: dict[str, Any]) -> None:
    # wknn: one fix per scan, every batch has one; every navigating one carried navigation
    assert wknn["fixes_per_batch_plain"] == wknn["fixes_per_batch_navigating"] == 1.0
    assert wknn["navigating_batches_without_navigation"] == 0
    assert wknn["arrivals"] == 0
    assert wknn["steps_without_path"] == 0
    assert 0.0 <= wknn["off_route_share"] <= 1.0


def test_bytes_navigation_adds(wknn: dict[str, Any]) -> None:
    assert wknn["navigation_state_bytes"] > 100  # a route, its steps, the progress
    assert wknn["fix_navigation_bytes"] > 100  # the instruction, the steps, the snap
    # the navigation state and the answer's navigation (in the body and the newest fix)
    assert wknn["log_entry_bytes_added"] >= wknn["navigation_state_bytes"]
    assert wknn["answer_bytes_added"] == wknn["fix_navigation_bytes"] - len("null")
    assert wknn["snapshot_bytes_plain"] > wknn["log_entry_bytes_plain"] > 0
    added = wknn["log_entry_bytes_added"], wknn["snapshot_bytes_added"]
    expected = ((SNAPSHOT_EVERY - 1) * added[0] + added[1]) / SNAPSHOT_EVERY
    assert wknn["store_bytes_added"] == pytest.approx(expected + 2 * wknn["answer_bytes_added"])


def test_navigation_alone_and_its_profile(wknn: dict[str, Any]) -> None:
    assert wknn["navigate_us_per_fix"] > 0
    for key in ("profile", "profile_cumulative"):
        rows = wknn[key]
        assert 0 < len(rows) <= 12
        for row in rows:
            assert set(row) == {
                "function", "calls_per_fix", "own_us_per_fix", "cumulative_us_per_fix",
            }  # fmt: skip
            assert row["cumulative_us_per_fix"] >= row["own_us_per_fix"] >= 0
    own = [row["own_us_per_fix"] for row in wknn["profile"]]
    assert own == sorted(own, reverse=True)
    names = [row["function"] for row in wknn["profile_cumulative"]]
    assert any("(navigate)" in name for name in names)  # the service's own functions


def test_refuses_what_it_cannot_measure() -> None:
    with pytest.raises(ValueError, match="even"):
        navigation_bench(blocks=3)
    with pytest.raises(ValueError, match="two groups"):
        navigation_bench(sessions=1)
