"""Magnetic profile matching: a walked profile is found where it was walked, and its
indicators have their closed forms (SS from the gradients, WD from the candidates)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.positioning.magnetic.profile_matching import lattice, match
from server.positioning.mapping.magnetic_gridding import grid_from_samples


def field_ut(xy: np.ndarray) -> np.ndarray:
    x, y = xy[..., 0], xy[..., 1]
    out: np.ndarray = 45.0 + 6.0 * np.sin(x / 3.1) + 4.0 * np.cos(y / 2.3 + 1.0) + 0.2 * x
    return out


def grid_of(field, size_m: float = 40.0):  # type: ignore[no-untyped-def]
    gx, gy = np.meshgrid(np.arange(0.0, size_m, 0.25), np.arange(0.0, size_m, 0.25))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    return grid_from_samples(xy, field(xy), extent=(0.0, 0.0, size_m, size_m))


def test_the_lattice_fills_the_circle() -> None:
    pts = lattice((10.0, 10.0), 2.0, 1.0)
    assert len(pts) == 13  # the points of the integer lattice within 2 of the centre
    assert np.all(np.hypot(*(pts - 10.0).T) <= 2.0)


def test_a_walked_profile_is_found_where_it_was_walked() -> None:
    grid = grid_of(field_ut)
    # an L-shaped walk of ten 0.7 m steps ending at (21, 17)
    track = np.array(
        [(14.7 + 0.7 * k, 14.0) for k in range(6)] + [(18.2, 14.0 + 0.75 * k) for k in range(1, 5)]
    )
    end = track[-1]
    truth = end + np.array([2.8, 0.0])  # the same walk 2.8 m further east
    profile = field_ut(track + (truth - end))
    found = match(grid, track - end, profile, centre=(float(end[0]), float(end[1])), radius_m=8.0)
    assert found is not None
    # the mean of the five likeliest candidates of a 1 m lattice (eq 12), against a
    # search circle of 8 m
    assert math.hypot(found.x_m - truth[0], found.y_m - truth[1]) < 1.0
    assert found.candidates > 150
    assert found.ss_m == pytest.approx(
        50.0 * np.mean(1.0 / np.maximum(np.abs(profile[1:] - profile[0]), 0.1))
    )


def test_a_flat_field_gives_the_closed_form_indicators() -> None:
    grid = grid_of(lambda xy: np.full(xy.shape[0], 50.0))
    offsets = np.array([[-2.0, 0.0], [-1.0, 0.0], [0.0, 0.0]])
    found = match(
        grid, offsets, np.full(3, 50.0), centre=(20.0, 20.0), radius_m=1.0, kappa=5, kappa_d=4
    )
    assert found is not None
    # five candidates (the centre and its four neighbours), all alike: the fix is their
    # mean, SS is alpha over the least gradient and each point's DSF the mean distance
    # to the other four: 1 for the centre, (1 + 2 + 2 sqrt 2) / 4 for the others
    assert found.candidates == 5
    assert (found.x_m, found.y_m) == pytest.approx((20.0, 20.0))
    assert found.ss_m == pytest.approx(50.0 / 0.1)
    assert found.wd_m == pytest.approx((1.0 + (3.0 + 2.0 * math.sqrt(2.0))) / 5.0)


def test_no_fix_without_enough_known_candidates() -> None:
    grid = grid_of(field_ut, size_m=10.0)
    offsets = np.array([[-1.0, 0.0], [0.0, 0.0]])
    assert match(grid, offsets, np.array([40.0, 41.0]), centre=(80.0, 80.0), radius_m=5.0) is None
    assert match(grid, offsets[:1], np.array([40.0]), centre=(5.0, 5.0), radius_m=3.0) is None
