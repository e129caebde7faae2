"""The move of ``particle_move`` (``papers/001_*`` Algorithm 1 lines 8-9) in the door
corridor of ``toy_plans``: the step without noise, refused moves, the door."""

from __future__ import annotations

import math

import numpy as np
import pytest

from server.positioning.filters.particle import step
from server.positioning.filters.particle_cloud import ParticleParams
from server.positioning.filters.particle_estimate import estimate
from server.positioning.filters.particle_move import move
from server.positioning.filters.particle_resampling import (
    alive,
    effective_sample_size,
    systematic_resample,
)
from tests.support.toy_plans import assert_normalised, cloud, door_map, door_valid_move


def test_move_follows_algorithm_1_line_8_without_noise() -> None:
    params = ParticleParams(step_sd_m=0.0, heading_sd_rad=0.0)
    p = cloud([(5.0, 1.0), (10.0, 2.0)])
    rng = np.random.default_rng(0)
    north = move(p, 0.7, 0.0, rng, params, door_valid_move)  # clockwise from north
    np.testing.assert_allclose(north.xy, [(5.0, 1.7), (10.0, 2.7)], atol=1e-6)
    east = move(p, 0.7, math.pi / 2, rng, params, door_valid_move)
    np.testing.assert_allclose(east.xy, [(5.7, 1.0), (10.7, 2.0)], atol=1e-6)
    assert east.log_w.tolist() == p.log_w.tolist()
    assert p.xy.tolist() == [[5.0, 1.0], [10.0, 2.0]]  # the input is not touched


def test_refused_moves_kill_and_leave_the_particle_in_place() -> None:
    params = ParticleParams(step_sd_m=0.0, heading_sd_rad=0.0)
    # north by 1 m: the first hits the side wall, the second stays inside
    p = cloud([(5.0, 3.5), (10.0, 1.0)], weights=[0.3, 0.7])
    q = move(p, 1.0, 0.0, np.random.default_rng(0), params, door_valid_move)
    np.testing.assert_allclose(q.xy, [(5.0, 3.5), (10.0, 2.0)], atol=1e-6)
    assert q.log_w[0] == -np.inf
    assert q.log_w[1] == 0.0  # renormalised: the survivor holds all the weight
    # everyone killed: the cloud is dead and stays dead
    dead = move(q, 10.0, 0.0, np.random.default_rng(0), params, door_valid_move)
    assert not alive(dead)
    assert effective_sample_size(dead) == 0.0
    assert_normalised(dead)
    with pytest.raises(ValueError, match="dead"):
        estimate(dead)
    with pytest.raises(ValueError, match="dead"):
        systematic_resample(dead, np.random.default_rng(0))
    again = step(dead, 0.7, 0.0, 45.0, np.random.default_rng(0), params, door_valid_move, door_map)
    assert not alive(again)


def test_moves_through_the_door_only() -> None:
    params = ParticleParams(step_sd_m=0.0, heading_sd_rad=0.0)
    p = cloud([(19.5, 2.0), (19.5, 1.0), (19.5, 3.0)])
    q = move(p, 1.0, math.pi / 2, np.random.default_rng(0), params, door_valid_move)
    np.testing.assert_allclose(q.xy, [(20.5, 2.0), (19.5, 1.0), (19.5, 3.0)], atol=1e-6)
    assert np.isfinite(q.log_w).tolist() == [True, False, False]
