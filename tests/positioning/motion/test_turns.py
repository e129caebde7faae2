"""Turn and straight-walk labels per step (``papers/003_*`` section III) on step headings."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.typing import NDArray

from server.positioning.model import state_codec
from server.positioning.motion.turns import (
    STRAIGHT,
    SUSPECT,
    TURN,
    TurnParams,
    TurnState,
    classify_steps,
    initial_turns,
)


def classify(
    headings_deg: list[float], params: TurnParams | None = None
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    params = params or TurnParams()
    _, status, segment = classify_steps(initial_turns(params), np.radians(headings_deg), params)
    return status, segment


def test_a_straight_walk_is_straight() -> None:
    rng = np.random.default_rng(1)
    headings = list(40.0 + rng.uniform(-2.0, 2.0, 60))
    status, segment = classify(headings)
    assert (status == STRAIGHT).all()
    assert (segment == 0).all()


def test_a_straight_walk_across_the_wrap_is_straight() -> None:
    status, _ = classify([178.0, -179.0, 179.0, -178.0, 180.0, -180.0, 177.0])
    assert (status == STRAIGHT).all()


def test_a_slow_sway_of_5_degrees_stays_straight() -> None:
    headings = list(90.0 + 5.0 * np.sin(2.0 * np.pi * np.arange(80) / 20.0))
    status, segment = classify(headings)
    assert (status == STRAIGHT).all()
    assert (segment == 0).all()


def test_a_right_angle_turn_is_a_turn_and_starts_a_segment() -> None:
    headings = [0.0] * 20 + [30.0, 60.0, 90.0] + [90.0] * 20
    status, segment = classify(headings)
    assert (status[:20] == STRAIGHT).all()
    assert status[20] == SUSPECT  # 30 deg from the last straight step: not more than λ_h
    assert (status[21:23] == TURN).all()
    # the turn lasts while the window still holds pre-turn headings
    assert (status[23:26] == TURN).all()
    assert (status[26:] == STRAIGHT).all()
    assert (segment[:26] == 0).all()
    assert (segment[26:] == 1).all()


def test_a_suspected_turn_that_comes_back_starts_a_new_segment() -> None:
    headings = [0.0] * 10 + [15.0, 0.0] + [0.0] * 10
    status, segment = classify(headings)
    assert (status[10:12] == SUSPECT).all()
    assert segment[-1] == 1
    assert (status[-1:] == STRAIGHT).all()


def test_turn_classification_is_incremental() -> None:
    rng = np.random.default_rng(2)
    headings = np.radians(
        np.concatenate([np.zeros(15), np.linspace(0, 90, 6), np.full(15, 90.0)])
        + rng.normal(0.0, 1.0, 36)
    )
    params = TurnParams()
    _, status, segment = classify_steps(initial_turns(params), headings, params)
    state = initial_turns(params)
    parts = []
    for chunk in np.array_split(headings, [4, 17, 18, 30]):
        state, s, g = classify_steps(
            state_codec.from_arrays(TurnState, state_codec.to_arrays(state)), chunk, params
        )
        parts.append((s, g))
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), status)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), segment)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"window_steps": 1}, "window_steps"),
        ({"lambda_low_rad": 0.0}, "lambda_low_rad: must be greater than 0"),
        (
            {"lambda_low_rad": 0.6, "lambda_high_rad": 0.5},
            "lambda_high_rad: must be above lambda_low_rad",
        ),
    ],
)
def test_turn_params_are_validated(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TurnParams(**kwargs)  # type: ignore[arg-type]
