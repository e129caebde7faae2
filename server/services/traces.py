"""Recorded walks in one shape: built from our own events, joined, stored as bytes.

The map builder reads a walk as a ``datasets.walk.Walk`` (scans, raw motion samples, the
known positions as waypoints), whatever it came as: an ILC 2.0 path file, or our own events
(a JSON upload, the batches of a session offered for map building). This module makes
that walk from events (``trace_from_events``), joins walks cut into pieces
(``join_traces``), finds its steps (``walk_steps``, ``anchored_steps``) and encodes a
walk as one array container (``encode_trace`` / ``decode_trace``, ``storage.codec``:
nothing pickled, a corrupt blob raises ``CodecError``).

From events: scans keep their readings; IMU blocks are concatenated per sensor (the
rotation vector keeps its vector part, sign chosen so the scalar part is not negative,
as ILC files carry it); ``mag`` events with a field vector join the magnetometer samples
(magnitude-only ones carry nothing a map can place and are dropped); phone-detected
steps are kept as ``Walk.steps`` (placement uses them when the raw samples give none, see
``upload_contribution``); satellite fixes are (``gnss``: rows ``[t, lat, lon, accuracy,
hdop]``, NaN for a missing HDOP). A block whose magnetometer is uncalibrated marks the
whole walk's magnetometer so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from server.datasets.walk import Walk
from server.positioning.model.events import (
    BleEvent,
    Event,
    GnssEvent,
    ImuEvent,
    MagEvent,
    RadioReading,
    StepEvent,
    WifiEvent,
)
from server.positioning.motion.step_tracker import StepBlock, TrackerParams, initial_tracker, track
from server.storage.codec import array_to_str, compress_arrays, decompress_arrays, str_to_array

CONTENT_TYPE = "application/vnd.indoorpos.trace"
STEP_BLOCK_MS = 1000  # raw samples reach the step tracker in blocks of this length
# shorter walks say more about the waypoint spacing than about steps
MIN_ANCHORED_PATH_M = 5.0
_SENSORS = ("accel", "gyro", "magnetic", "rotation")


def _rows(parts: Sequence[NDArray[np.float64]], width: int) -> NDArray[np.float64]:
    rows = np.concatenate([p.reshape(-1, width) for p in parts]) if parts else np.empty((0, width))
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    # a sample sent twice (a retried batch) is kept once
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.diff(rows[:, 0]) > 0
    return np.ascontiguousarray(rows[keep])


def _trace(
    path_id: str,
    floor: str,
    anchors: NDArray[np.float64],
    wifi: Sequence[WifiEvent],
    ble: Sequence[BleEvent],
    sensors: dict[str, NDArray[np.float64]],
    uncalibrated: frozenset[str],
    gnss: NDArray[np.float64],
    steps: NDArray[np.float64],
) -> Walk:
    times = [anchors[:, 0], gnss[:, 0], *(a[:, 0] for a in sensors.values())]
    scan_t = [e.t_ms for e in wifi] + [e.t_ms for e in ble]
    times.append(np.array(scan_t, dtype=np.float64))
    t_all = np.concatenate(times)
    order = np.argsort(anchors[:, 0], kind="stable")
    return Walk(
        path_id=path_id,
        floor=floor,
        waypoint_t_ms=anchors[order, 0].astype(np.int64),
        waypoint_xy_m=np.ascontiguousarray(anchors[order, 1:3]),
        wifi=tuple(sorted(wifi, key=lambda e: e.t_ms)),
        ble=tuple(sorted(ble, key=lambda e: e.t_ms)),
        accel=sensors["accel"],
        gyro=sensors["gyro"],
        magnetic=sensors["magnetic"],
        rotation=sensors["rotation"],
        uncalibrated=uncalibrated,
        t_first_ms=int(t_all.min()) if t_all.size else 0,
        t_last_ms=int(t_all.max()) if t_all.size else 0,
        gnss=gnss,
        steps=steps,
    )


def trace_from_events(
    events: Sequence[Event],
    anchors: Sequence[tuple[int, float, float]] = (),
    *,
    path_id: str = "",
    floor: str = "",
) -> Walk:
    """A walk from our events and its known positions ``(t_ms, x_m, y_m)``."""
    parts: dict[str, list[NDArray[np.float64]]] = {name: [] for name in _SENSORS}
    uncalibrated: set[str] = set()
    for e in events:
        if isinstance(e, ImuEvent):
            parts["accel"].append(e.accel)
            parts["gyro"].append(e.gyro)
            parts["magnetic"].append(e.magnetic)
            if e.magnetic.shape[0] and not e.magnetic_calibrated:
                uncalibrated.add("magnetic")
            if e.rotation.shape[0]:
                q = e.rotation.copy()
                q[q[:, 4] < 0, 1:] *= -1.0  # the same rotation with w >= 0
                parts["rotation"].append(q[:, :4])
        elif isinstance(e, MagEvent) and e.field_ut is not None:
            parts["magnetic"].append(np.array([[e.t_ms, *e.field_ut]], dtype=np.float64))
    sensors = {name: _rows(parts[name], 4) for name in _SENSORS}
    fixes = [
        (e.t_ms, e.lat_deg, e.lon_deg, e.accuracy_m, np.nan if e.hdop is None else e.hdop)
        for e in events
        if isinstance(e, GnssEvent)
    ]
    steps = [(e.t_ms, e.length_m, e.heading_rad) for e in events if isinstance(e, StepEvent)]
    return _trace(
        path_id,
        floor,
        np.asarray(anchors, dtype=np.float64).reshape(-1, 3),
        [e for e in events if isinstance(e, WifiEvent)],
        [e for e in events if isinstance(e, BleEvent)],
        sensors,
        frozenset(uncalibrated),
        _rows([np.array(fixes, dtype=np.float64).reshape(-1, 5)], 5),
        _rows([np.array(steps, dtype=np.float64).reshape(-1, 3)], 3),
    )


def join_traces(traces: Sequence[Walk], *, path_id: str = "", floor: str = "") -> Walk:
    """One walk from its pieces (e.g. a session's batches), in time order."""
    anchors = [np.column_stack([t.waypoint_t_ms, t.waypoint_xy_m]) for t in traces]
    sensors = {name: _rows([getattr(t, name) for t in traces], 4) for name in _SENSORS}
    return _trace(
        path_id,
        floor,
        np.concatenate(anchors).reshape(-1, 3) if anchors else np.empty((0, 3)),
        [e for t in traces for e in t.wifi],
        [e for t in traces for e in t.ble],
        sensors,
        frozenset().union(*(t.uncalibrated for t in traces)),
        _rows([t.gnss for t in traces], 5),
        _rows([t.steps for t in traces], 3),
    )


def _scans(prefix: str, scans: Sequence[WifiEvent | BleEvent]) -> dict[str, np.ndarray]:
    emitters = sorted({r.emitter for e in scans for r in e.readings})
    index = {k: i for i, k in enumerate(emitters)}
    readings = [
        (i, index[r.emitter], r.rssi_dbm, math.nan if r.age_ms is None else r.age_ms)
        for i, e in enumerate(scans)
        for r in e.readings
    ]
    table = np.array(readings, dtype=np.float64).reshape(-1, 4)
    return {
        f"{prefix}_t": np.array([e.t_ms for e in scans], dtype=np.int64),
        f"{prefix}_scan": table[:, 0].astype(np.int32),
        f"{prefix}_emitter": table[:, 1].astype(np.int32),
        f"{prefix}_rssi": table[:, 2].astype(np.float32),
        f"{prefix}_age": table[:, 3],  # ms, NaN: not known
        f"{prefix}_names": str_to_array("\n".join(emitters)),
    }


def _unscans(a: dict[str, np.ndarray], prefix: str) -> list[list[RadioReading]]:
    text = array_to_str(a[f"{prefix}_names"])
    names = text.split("\n") if text else []
    scans: list[list[RadioReading]] = [[] for _ in range(len(a[f"{prefix}_t"]))]
    n = len(a[f"{prefix}_scan"])
    ages = a.get(f"{prefix}_age", np.full(n, np.nan))  # traces stored before ages
    for scan, emitter, rssi, age in zip(
        a[f"{prefix}_scan"].tolist(),
        a[f"{prefix}_emitter"].tolist(),
        a[f"{prefix}_rssi"].tolist(),
        ages.tolist(),
        strict=True,
    ):
        scans[scan].append(RadioReading(names[emitter], rssi, None if math.isnan(age) else age))
    return scans


def encode_trace(trace: Walk) -> bytes:
    """The walk as one compressed array container (deterministic: equal walks, equal bytes)."""
    arrays: dict[str, np.ndarray] = {
        "anchors": np.column_stack([trace.waypoint_t_ms, trace.waypoint_xy_m]).astype(np.float64),
        "floor": str_to_array(trace.floor),
        "uncalibrated": str_to_array(",".join(sorted(trace.uncalibrated))),
        **{name: getattr(trace, name) for name in _SENSORS},
        "gnss": trace.gnss.astype(np.float64),
        **_scans("wifi", trace.wifi),
        **_scans("ble", trace.ble),
    }
    if trace.steps.shape[0]:  # walks without phone steps keep the bytes they had
        arrays["steps"] = trace.steps.astype(np.float64)
    return compress_arrays(arrays)


def decode_trace(data: bytes, path_id: str = "") -> Walk:
    """The inverse of ``encode_trace``; ``CodecError`` (or ``KeyError``) for foreign bytes."""
    a = decompress_arrays(data)
    wifi = [
        WifiEvent(int(t), tuple(r))
        for t, r in zip(a["wifi_t"].tolist(), _unscans(a, "wifi"), strict=True)
    ]
    ble = [
        BleEvent(int(t), tuple(r))
        for t, r in zip(a["ble_t"].tolist(), _unscans(a, "ble"), strict=True)
    ]
    marks = array_to_str(a["uncalibrated"])
    return _trace(
        path_id,
        array_to_str(a["floor"]),
        a["anchors"].reshape(-1, 3),
        wifi,
        ble,
        {name: a[name].reshape(-1, 4) for name in _SENSORS},
        frozenset(marks.split(",")) if marks else frozenset(),
        a["gnss"].reshape(-1, 5) if "gnss" in a else np.empty((0, 5)),
        a["steps"].reshape(-1, 3) if "steps" in a else np.empty((0, 3)),
    )


def walk_steps(trace: Walk, params: TrackerParams, block_ms: int = STEP_BLOCK_MS) -> StepBlock:
    """Every step the server finds in the walk's raw motion samples (``step_tracker``, the
    samples fed in blocks of ``block_ms`` as a phone would send them), in time order."""
    state = initial_tracker(params)
    blocks: list[StepBlock] = []
    for imu in trace.imu_events(block_ms):
        state, block = track(state, imu, params)
        blocks.append(block)
    return _steps(blocks, None)


def anchored_steps(trace: Walk, params: TrackerParams) -> StepBlock | None:
    """The walk's steps between its first and last waypoint (its anchors); None when it
    has fewer than two or they span less than ``MIN_ANCHORED_PATH_M`` along the waypoints."""
    wp_t = trace.waypoint_t_ms
    if wp_t.size < 2:
        return None
    path_m = float(np.linalg.norm(np.diff(trace.waypoint_xy_m, axis=0), axis=1).sum())
    if path_m < MIN_ANCHORED_PATH_M:
        return None
    steps = walk_steps(trace, params)
    return _steps([steps], (steps.t_ms > wp_t[0]) & (steps.t_ms <= wp_t[-1]))


def _steps(blocks: Sequence[StepBlock], keep: NDArray[np.bool_] | None) -> StepBlock:
    """The blocks joined into one, then (with ``keep``) the steps kept."""

    def cat(name: str, dtype: type[np.generic]) -> NDArray[Any]:
        parts = [np.asarray(getattr(b, name), dtype=dtype) for b in blocks]
        joined = np.concatenate(parts) if parts else np.empty(0, dtype=dtype)
        return joined if keep is None else joined[keep]

    return StepBlock(
        t_ms=cat("t_ms", np.int64),
        length_m=cat("length_m", np.float64),
        heading_rad=cat("heading_rad", np.float64),
        north_rad=cat("north_rad", np.float64),
        status=cat("status", np.int64),
        segment=cat("segment", np.int64),
        magnitude_ut=cat("magnitude_ut", np.float64),
    )
