"""Sensor geometry: headings of a phone pointing along the cardinals, by hand and tilted."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from server.positioning.motion.sensor_geometry import (
    G,
    compass_heading,
    gravity_direction,
    heading_from_yaw,
    rotation_heading,
    vertical_rate,
)
from tests.support.synthetic_phone import (
    EARTH_FIELD_UT,
    T0_MS,
    angle_error_deg,
    rotation,
    samples,
    to_phone,
)

CARDINALS_DEG = [0.0, 90.0, 180.0, -90.0]
TILTS_DEG = [(0.0, 0.0), (30.0, 0.0), (0.0, 30.0), (-30.0, 0.0), (0.0, -30.0)]


@pytest.mark.parametrize("heading_deg", CARDINALS_DEG)
@pytest.mark.parametrize(("pitch_deg", "roll_deg"), TILTS_DEG)
def test_headings_for_a_phone_pointing_north_east_south_west(
    heading_deg: float, pitch_deg: float, roll_deg: float
) -> None:
    psi = -math.radians(heading_deg)
    R = rotation(np.array([psi]), np.radians([pitch_deg]), np.radians([roll_deg]))
    up = to_phone(R, np.array([0.0, 0.0, 1.0]))
    field = to_phone(R, EARTH_FIELD_UT)
    expected = math.radians(heading_deg)

    assert angle_error_deg(compass_heading(samples(np.zeros(1), field), up), expected)[0] < 1e-9
    q = Rotation.from_matrix(R[0]).as_quat()  # [x, y, z, w]
    assert angle_error_deg(rotation_heading(np.array([[T0_MS, *q]]))[0, 1], expected) < 1e-9
    unknown_w = np.array([[T0_MS, *(q * np.sign(q[3]))[:3], np.nan]])
    assert angle_error_deg(rotation_heading(unknown_w)[0, 1], expected) < 1e-4
    assert angle_error_deg(heading_from_yaw(np.array([psi]))[0], expected) < 1e-9
    # a flat phone pointing north reads heading 0; gravity and the field in phone axes
    np.testing.assert_allclose(gravity_direction(samples(np.zeros(1), G * up)), up)


def test_compass_heading_of_a_flat_phone_by_hand() -> None:
    # flat, top edge east: phone x points south, y east; the field points north and down
    field = np.array([[T0_MS, -25.7, 0.0, -30.6]])
    up = np.array([[0.0, 0.0, 1.0]])
    assert compass_heading(field, up)[0] == pytest.approx(math.pi / 2)
    # rotation vector of a flat phone turned 90 deg clockwise: -90 deg about up
    s = math.sin(math.radians(-45.0))
    assert rotation_heading(np.array([[T0_MS, 0.0, 0.0, s, math.cos(math.radians(-45.0))]]))[
        0, 1
    ] == pytest.approx(math.pi / 2)


def test_vertical_rate_is_the_rate_about_up() -> None:
    R = rotation(np.array([0.4]), np.radians([20.0]), np.radians([-10.0]))
    up = to_phone(R, np.array([0.0, 0.0, 1.0]))
    east = to_phone(R, np.array([1.0, 0.0, 0.0]))
    gyro = samples(np.zeros(1), 0.3 * up + 0.2 * east)
    assert vertical_rate(gyro, up)[0] == pytest.approx(0.3)


def test_compass_heading_without_a_horizontal_field_is_nan() -> None:
    up = np.array([[0.0, 0.0, 1.0]])
    assert np.isnan(compass_heading(np.array([[T0_MS, 0.0, 0.0, -40.0]]), up)).all()
