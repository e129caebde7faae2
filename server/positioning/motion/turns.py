"""Turns and straight walking, per step, from the step headings (``papers/003_*`` section III).

Per step, ``Δh_max`` is the largest heading difference within a sliding window of the last
``window_steps`` step headings; while it stays at or below ``λ_l`` the walk is straight;
above ``λ_l`` a turn is suspected and only declared once the heading has changed by more
than ``λ_h`` since the last straight step. The paper gives no values; we use 10° and 30°
(a straight corridor walk with a hand-held phone sways a few degrees; corridor turns are
45-90°). Each straight stretch gets its own segment id, the unit that ``straight_lines``
fits a line to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from annotated_types import Ge, Le
from numpy.typing import NDArray

from server.positioning.model.params import ParamError, Params, Positive

FloatArray = NDArray[np.float64]

STRAIGHT, SUSPECT, TURN = 0, 1, 2


@dataclass(frozen=True)
class TurnParams(Params):
    """``papers/003_*`` section III turn detection; the paper gives no λ values."""

    window_steps: Annotated[int, Ge(2), Le(100)] = 5
    lambda_low_rad: Positive = math.radians(10.0)  # λ_l: heading sway allowed on a straight
    lambda_high_rad: Positive = math.radians(30.0)  # λ_h: total change that makes a turn

    def check(self) -> None:
        if not self.lambda_low_rad < self.lambda_high_rad:
            raise ParamError("lambda_high_rad", "must be above lambda_low_rad")


@dataclass(frozen=True)
class TurnState:
    """Recent step headings (unwrapped, NaN-padded, oldest first), the heading of the
    last straight step and the current status."""

    recent: FloatArray
    reference: float
    status: int
    segment: int  # increases whenever a new straight-line model starts


def initial_turns(params: TurnParams) -> TurnState:
    return TurnState(np.full(params.window_steps, np.nan), math.nan, STRAIGHT, 0)


def classify_steps(
    state: TurnState, headings: FloatArray, params: TurnParams
) -> tuple[TurnState, NDArray[np.int64], NDArray[np.int64]]:
    """Label each step straight, suspected turn or turn (``papers/003_*`` section III).

    Parameters
    ----------
    state : TurnState
    headings : ndarray, shape (k,)
        Gyro heading at each step, radians (any continuous or wrapped form).
    params : TurnParams

    Returns
    -------
    state : TurnState
    status : ndarray, shape (k,), int64
        ``STRAIGHT`` while ``Δh_max <= λ_l``, ``SUSPECT`` above it, ``TURN`` once the
        heading has moved more than ``λ_h`` from the last straight step.
    segment : ndarray, shape (k,), int64
        Straight-line model id of each step: a new one starts when the walk is straight
        again after a suspected turn or a turn.
    """
    recent = state.recent.copy()
    reference, current, segment = state.reference, state.status, state.segment
    status = np.empty(headings.size, dtype=np.int64)
    segments = np.empty(headings.size, dtype=np.int64)
    for i, h in enumerate(np.asarray(headings, dtype=np.float64)):
        last = recent[-1]
        if not math.isnan(last):
            h = last + float(np.angle(np.exp(1j * (h - last))))  # unwrap onto the window
        recent = np.roll(recent, -1)
        recent[-1] = h
        known = recent[~np.isnan(recent)]
        spread = float(known.max() - known.min())
        if spread <= params.lambda_low_rad:
            if current != STRAIGHT:
                segment += 1
            current, reference = STRAIGHT, h
        elif math.isnan(reference) or abs(h - reference) > params.lambda_high_rad:
            current = TURN
        elif current != TURN:
            current = SUSPECT
        status[i], segments[i] = current, segment
    return TurnState(recent, reference, current, segment), status, segments
