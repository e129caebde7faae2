"""Magnetic field: fixed anomalies of the stated size; the phone frame keeps invariants."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from client_sim.building import synthesize_building
from client_sim.magnetic import synthesize_magnetic, to_phone_frame


def test_field_is_fixed_with_anomalies_of_the_stated_size() -> None:
    building = synthesize_building(np.random.default_rng(0))
    field = synthesize_magnetic(building, np.random.default_rng(1))
    grid = building.floor(0).walkable_grid(0.5)
    b = field.field_ut(grid, 0)
    assert np.array_equal(b, field.field_ut(grid, 0))
    assert b.mean(axis=0) == pytest.approx([1.5, 21.0, -43.0], abs=1.5)
    assert b.std(axis=0) == pytest.approx([4.0, 4.0, 4.0], rel=0.3)
    assert not np.allclose(b, field.field_ut(grid, 1))  # each floor its own anomalies
    noisy = field.sample(grid, 0, np.random.default_rng(2))
    assert np.std(noisy - b) == pytest.approx(0.5, rel=0.1)


@given(
    heading=st.floats(-10.0, 10.0),
    vector=st.tuples(*(st.floats(-100.0, 100.0) for _ in range(3))),
)
def test_phone_frame_keeps_magnitude_vertical_and_horizontal(
    heading: float, vector: tuple[float, float, float]
) -> None:
    b = np.array([vector])
    phone = to_phone_frame(b, heading)
    assert np.linalg.norm(phone) == pytest.approx(np.linalg.norm(b), abs=1e-9)
    assert phone[0, 2] == b[0, 2]
    assert np.hypot(*phone[0, :2]) == pytest.approx(np.hypot(*b[0, :2]), abs=1e-9)


def test_phone_facing_north_east_sees_north_ahead_and_left() -> None:
    north = np.array([[0.0, 20.0, -40.0]])
    assert to_phone_frame(north, 0.0) == pytest.approx(np.array([[0.0, 20.0, -40.0]]))
    # facing east, north is on the left (negative x)
    assert to_phone_frame(north, np.pi / 2) == pytest.approx(np.array([[-20.0, 0.0, -40.0]]))
