"""Raw IMU blocks in, steps out: each with its time, length, phone heading and turn status.

This joins the pieces of PDR for the fusion engines, across batches:

* steps and their lengths from the accelerometer (``server.positioning.motion.pdr``);
* the phone heading from one of three sources (``attitude_ekf``, ``heading_fusion``,
  ``sensor_geometry``):

  - ``"attitude"``: the yaw of the attitude-determination EKF (``papers/002_*`` eq 9-17),
    gyro-driven with roll and pitch from gravity;
  - ``"fused"``: gyro integration corrected by the compass during quasi-static magnetic
    field periods (``papers/003_*`` section III);
  - ``"rotation"``: the phone's rotation vector where it sends one, ``"fused"``
    otherwise;

* turn and straight-walk labels per step (``server.positioning.motion.turns``, ``papers/003_*``
  section III).

The heading of a step is the phone heading at the step's time, interpolated from a short
history carried in the state, so a step found one batch late still gets the heading of its
own moment. A step is only certain some 0.3 s after its valley, so a step at the end of
a batch comes out with the next one, after any scan of the first batch that followed it:
the engines then apply it after that scan. Headings are clockwise from the source's
north (magnetic north for the compass, an arbitrary but fixed origin for the gyro-only
yaw); the engines use their changes and learn the offset to the map frame themselves.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Literal, NamedTuple

import numpy as np
from numpy.typing import NDArray

from server.positioning.filters.kalman import wrap_angle
from server.positioning.model.events import BleEvent, Event, ImuEvent, WifiEvent
from server.positioning.model.params import Params, Positive
from server.positioning.model.state_codec import shape
from server.positioning.motion import pdr
from server.positioning.motion.attitude_ekf import (
    AttitudeParams,
    AttitudeState,
    attitude_ekf,
    initial_attitude,
)
from server.positioning.motion.heading_fusion import (
    HeadingParams,
    HeadingState,
    fuse_heading,
    initial_heading,
)
from server.positioning.motion.sensor_geometry import heading_from_yaw, rotation_heading
from server.positioning.motion.turns import (
    STRAIGHT,
    TurnParams,
    TurnState,
    classify_steps,
    initial_turns,
)

FloatArray = NDArray[np.float64]

HeadingSource = Literal["attitude", "fused", "rotation"]

HISTORY_MS = 3000  # longer than any step can wait for its completing extreme


@dataclass(frozen=True)
class TrackerParams(Params):
    heading: HeadingSource = "fused"
    steps: pdr.PdrParams = field(default_factory=pdr.PdrParams)
    turns: TurnParams = field(default_factory=TurnParams)
    attitude: AttitudeParams = field(default_factory=AttitudeParams)
    fusion: HeadingParams = field(default_factory=HeadingParams)
    step_scale: Positive = 1.0  # multiplies the step-length model (per-person calibration)


@dataclass(frozen=True)
class StepBlock:
    """Steps found in one IMU block, in time order (all arrays shape (k,))."""

    t_ms: NDArray[np.int64]
    length_m: FloatArray
    heading_rad: FloatArray  # phone heading from the chosen source, wrapped to (-pi, pi]
    north_rad: FloatArray  # phone heading clockwise from north; NaN when not known
    status: NDArray[np.int64]  # turns.STRAIGHT / SUSPECT / TURN
    segment: NDArray[np.int64]
    magnitude_ut: FloatArray  # magnetic field strength at the step; NaN when not known

    def __len__(self) -> int:
        return int(self.t_ms.size)


@dataclass(frozen=True)
class TrackerState:
    detector: pdr.DetectorState
    turns: TurnState
    attitude: AttitudeState
    fusion: HeadingState
    # [t_ms, unwrapped heading] of the last HISTORY_MS
    history: FloatArray = field(metadata=shape(-1, 2))
    # the same for the north-referenced heading
    north_history: FloatArray = field(metadata=shape(-1, 2))
    # newest sample time processed per sensor (-inf: none)
    seen_ms: FloatArray = field(metadata=shape(5))
    # [t_ms, |B| µT] of the last HISTORY_MS
    field_history: FloatArray = field(metadata=shape(-1, 2))


def initial_tracker(params: TrackerParams) -> TrackerState:
    return TrackerState(
        detector=pdr.initial_detector(),
        turns=initial_turns(params.turns),
        attitude=initial_attitude(params.attitude),
        fusion=initial_heading(params.fusion),
        history=np.empty((0, 2)),
        north_history=np.empty((0, 2)),
        seen_ms=np.full(len(_SENSORS), -np.inf),
        field_history=np.empty((0, 2)),
    )


def _headings(
    state: TrackerState, imu: ImuEvent, params: TrackerParams
) -> tuple[TrackerState, FloatArray, FloatArray]:
    """Heading samples ``[t_ms, heading]`` of the block: from the chosen source, and
    referenced to north (rotation vector, else the compass-aided fusion once it has seen
    the compass; no rows when neither is known)."""
    none = np.empty((0, 2))
    north = none
    if imu.gyro.shape[0]:
        was_referenced = state.fusion.initialized
        fusion, fused = fuse_heading(state.fusion, imu.gyro, imu.accel, imu.magnetic, params.fusion)
        state = replace(state, fusion=fusion)
        if was_referenced:
            north = fused[:, :2]
    if imu.rotation.shape[0]:
        north = rotation_heading(imu.rotation)
    if params.heading == "attitude":
        if imu.gyro.shape[0] == 0:
            return state, none, north
        attitude, euler = attitude_ekf(state.attitude, imu.gyro, imu.accel, params.attitude)
        heading = np.column_stack([euler[:, 0], heading_from_yaw(euler[:, 1])])
        return replace(state, attitude=attitude), heading, north
    if params.heading == "rotation" and imu.rotation.shape[0]:
        return state, north, north
    return state, (fused[:, :2] if imu.gyro.shape[0] else none), north


def _extend_history(history: FloatArray, samples: FloatArray) -> FloatArray:
    """Append heading samples, unwrapped to continue the history."""
    if samples.shape[0] == 0:
        return history
    t = samples[:, 0]
    keep = t > history[-1, 0] if history.shape[0] else np.ones(t.size, dtype=bool)
    t, h = t[keep], samples[keep, 1]
    if t.size == 0:
        return history
    # continue from the last kept value, not from the wrapped one
    h = np.unwrap(np.concatenate([history[-1:, 1], h]))[history.shape[0] > 0 :]
    out: FloatArray = np.vstack([history, np.column_stack([t, h])])
    return out


def track(
    state: TrackerState, imu: ImuEvent, params: TrackerParams
) -> tuple[TrackerState, StepBlock]:
    """Advance the tracker by one IMU block; the steps it completes come out.

    Samples at or before the newest already processed of their sensor (a block sent
    twice, or overlapping the previous one) are dropped, so nothing is integrated twice.
    An uncalibrated magnetometer (``magnetic_calibrated`` false) is not used: its
    hard-iron offset would point the compass anywhere.
    """
    imu, seen = _new_samples(imu, state.seen_ms)
    state, heading_samples, north_samples = _headings(replace(state, seen_ms=seen), imu, params)
    history = _extend_history(state.history, heading_samples)
    north_history = _extend_history(state.north_history, north_samples)
    strength = np.column_stack([imu.magnetic[:, 0], np.linalg.norm(imu.magnetic[:, 1:], axis=1)])
    field_history = np.vstack([state.field_history, strength])
    detector, steps = pdr.detect_steps(state.detector, imu.accel, params.steps)
    state = replace(
        state,
        detector=detector,
        history=_recent(history),
        north_history=_recent(north_history),
        field_history=_recent(field_history),
    )
    if len(steps) == 0:
        empty = np.empty(0, dtype=np.int64)
        none = np.empty(0)
        return state, StepBlock(empty, none, none, none, empty, empty, none)
    t = steps.t_ms.astype(np.float64)
    heading = _at(history, t)
    lengths = pdr.step_lengths(steps, params.steps, params.step_scale)
    known = ~np.isnan(heading)
    status = np.full(len(steps), STRAIGHT, dtype=np.int64)
    segment = np.full(len(steps), state.turns.segment, dtype=np.int64)
    turns = state.turns
    if known.any():
        turns, status[known], segment[known] = classify_steps(turns, heading[known], params.turns)
    block = StepBlock(
        steps.t_ms,
        lengths,
        _wrap(heading),
        _wrap(_at(north_history, t)),
        status,
        segment,
        _at(field_history, t),
    )
    return replace(state, turns=turns), block


_SENSORS = ("accel", "gyro", "magnetic", "rotation", "pressure")


def _new_samples(imu: ImuEvent, seen_ms: FloatArray) -> tuple[ImuEvent, FloatArray]:
    """The block without samples already processed, and the newest time per sensor."""
    arrays = {}
    seen = seen_ms.copy()
    for i, name in enumerate(_SENSORS):
        samples = getattr(imu, name)
        samples = samples[samples[:, 0] > seen[i]] if samples.shape[0] else samples
        if samples.shape[0]:
            seen[i] = samples[-1, 0]
        arrays[name] = samples
    if not imu.magnetic_calibrated:
        arrays["magnetic"] = arrays["magnetic"][:0]
    return replace(imu, **arrays), seen


def _recent(history: FloatArray) -> FloatArray:
    """The last ``HISTORY_MS`` of a heading history."""
    if history.shape[0] == 0:
        return history
    recent: FloatArray = history[history[:, 0] >= history[-1, 0] - HISTORY_MS]
    return recent


def _at(history: FloatArray, t: FloatArray) -> FloatArray:
    """History interpolated at times ``t`` (NaN everywhere when it is empty)."""
    if history.shape[0] == 0:
        return np.full(t.size, np.nan)
    return np.interp(t, history[:, 0], history[:, 1])


def _wrap(angle: FloatArray) -> FloatArray:
    """Wrap to (-pi, pi], keeping NaN."""
    return np.where(np.isnan(angle), np.nan, wrap_angle(np.nan_to_num(angle)))


class Step(NamedTuple):
    """One step as the fusion engines consume it."""

    t_ms: int
    length_m: float
    heading_rad: float  # from the tracker's heading source
    north_rad: float  # clockwise from north; NaN when not known
    straight: bool  # part of a straight walk (turns.STRAIGHT)
    magnitude_ut: float = math.nan  # magnetic field strength at the step


Scan = WifiEvent | BleEvent


def timeline(
    state: TrackerState, events: Sequence[Event], params: TrackerParams
) -> tuple[TrackerState, list[Step | Scan]]:
    """The batch's IMU blocks turned into steps, merged with its scans in time order (a
    step before a scan of the same millisecond); other events are dropped."""
    items: list[tuple[int, int, Step | Scan]] = []
    imus = sorted((e for e in events if isinstance(e, ImuEvent)), key=lambda e: e.t_ms)
    for imu in imus:
        state, block = track(state, imu, params)
        for i in range(len(block)):
            step = Step(
                int(block.t_ms[i]),
                float(block.length_m[i]),
                float(block.heading_rad[i]),
                float(block.north_rad[i]),
                bool(block.status[i] == STRAIGHT),
                float(block.magnitude_ut[i]),
            )
            items.append((step.t_ms, 0, step))
    items += [(e.t_ms, 1, e) for e in events if isinstance(e, WifiEvent | BleEvent)]
    items.sort(key=lambda item: (item[0], item[1]))
    return state, [item for _, _, item in items]
