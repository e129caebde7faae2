"""A recorded walk: what the dataset readers produce and the map builder reads.

One shape for every source: an ILC 2.0 path file (``storage.ilc_trace_format``), an IPIN
GetSensorData log (the lab's ``datasets.ipin_log``), or our own events (an upload, the
batches of a session; ``trace_from_events`` below, kept as bytes by
``storage.trace_codec``). A walk is what the phone recorded and where it is known to have
been; what a reader could not read is in its report (``storage.text_records.ParseReport``),
not here.

Its views as events (``radio_events``, ``imu_events``, ``events``) are what a phone would
have posted, so a replayed walk and live phone traffic go through the same code.

From events (``trace_from_events``, the shape of an upload or of a session's batches
offered for map building): scans keep their readings; IMU blocks are concatenated per
sensor (the rotation vector keeps its vector part, sign chosen so the scalar part is not
negative, as ILC files carry it); ``mag`` events with a field vector join the magnetometer
samples (magnitude-only ones carry nothing a map can place and are dropped); phone-detected
steps are kept as ``Walk.steps`` (placement uses them when the raw samples give none);
satellite fixes are (``gnss``: rows ``[t, lat, lon, accuracy, hdop]``, NaN for a missing
HDOP). A block whose magnetometer is uncalibrated marks the whole walk's magnetometer so.
``join_traces`` joins a walk cut into pieces (a session's batches).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import (
    BleEvent,
    Event,
    GnssEvent,
    ImuEvent,
    MagEvent,
    StepEvent,
    WifiEvent,
)

IMU_BLOCK_MS = 1000
"""Phone time covered by one ``ImuEvent`` of ``Walk.imu_events``: a phone posting raw
samples about once a second (as the evaluation replays batches)."""


@dataclass(frozen=True, eq=False)
class Walk:
    """One recorded walk.

    Attributes
    ----------
    path_id : str
        The walk's name: its file name without ``.txt`` / ``.txt.xz``, an upload's id.
    floor : str
        Floor name, e.g. ``"F1"`` (``ilc.floor_level`` tells its level; ``""`` unknown).
    waypoint_t_ms : ndarray, shape (n_wp,), int64
        Ground-truth (anchor) times, sorted.
    waypoint_xy_m : ndarray, shape (n_wp, 2), float64
        Ground-truth positions in the floor-map frame (x east, y north), metres.
    wifi : tuple of WifiEvent
        One event per scan, sorted by time; readings keyed by lower-case BSSID.
    ble : tuple of BleEvent
        Beacon scans sorted by time (the readers group rows into scans of
        ``events.BLE_WINDOW_MS``, ``window_ble``); readings keyed by the beacon's MAC in
        lower case.
    accel, gyro, magnetic, rotation : ndarray, shape (n, 4), float64
        ``[t_ms, x, y, z]`` rows sorted by time: m/s², rad/s, µT, rotation-vector
        quaternion (x, y, z).
    uncalibrated : frozenset of str
        Streams (``"accel"``, ``"gyro"``, ``"magnetic"``) taken from uncalibrated
        records (their bias estimate subtracted) or sent uncalibrated.
    t_first_ms, t_last_ms : int
        First and last timestamp of the records read (0 and 0 when there are none).
    gnss : ndarray, shape (n_fix, 5), float64
        ``[t_ms, lat_deg, lon_deg, accuracy_m, hdop]`` satellite fixes (ILC files carry
        none; walks made of our own events and IPIN logs may); hdop NaN where unknown.
    pressure : ndarray, shape (n_p, 2), float64
        ``[t_ms, hPa]`` barometer rows sorted by time (ILC files carry none).
    waypoint_floor : ndarray, shape (n_wp,) or (0,), int64
        Level of each waypoint (0 ground floor, negative below) where the source gives
        one per waypoint (IPIN ``POSI`` lines); empty when the whole walk is on ``floor``.
    steps : ndarray, shape (n_steps, 3), float64
        ``[t_ms, length_m, heading_rad]`` of the steps the phone itself detected (our
        ``step`` events; heading clockwise from north), sorted by time; the datasets carry
        none (their steps are found in the raw samples).
    """

    path_id: str
    floor: str
    waypoint_t_ms: NDArray[np.int64]
    waypoint_xy_m: NDArray[np.float64]
    wifi: tuple[WifiEvent, ...]
    ble: tuple[BleEvent, ...]
    accel: NDArray[np.float64]
    gyro: NDArray[np.float64]
    magnetic: NDArray[np.float64]
    rotation: NDArray[np.float64]
    uncalibrated: frozenset[str]
    t_first_ms: int
    t_last_ms: int
    gnss: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 5)))
    pressure: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 2)))
    waypoint_floor: NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    steps: NDArray[np.float64] = field(default_factory=lambda: np.empty((0, 3)))

    @property
    def duration_ms(self) -> int:
        """Time from the first to the last record read, in ms."""
        return self.t_last_ms - self.t_first_ms

    def radio_events(self) -> list[WifiEvent | BleEvent]:
        """WiFi and BLE events merged and sorted by time (stable: WiFi first on ties)."""
        events: list[WifiEvent | BleEvent] = [*self.wifi, *self.ble]
        events.sort(key=lambda e: e.t_ms)
        return events

    def imu_events(self, block_ms: int = IMU_BLOCK_MS, motion: bool = True) -> list[ImuEvent]:
        """The motion and barometer samples cut into blocks of ``block_ms`` phone time, as
        a phone that sends raw samples would post them; without ``motion``, the barometer's
        only (what a phone posts to an engine that reads its steps but its barometer too).

        Block ``k`` holds the samples of every stream with ``t0 + k * block_ms <= t <
        t0 + (k + 1) * block_ms``, ``t0`` being the first sample of any stream, and its
        ``t_ms`` is that start; blocks without any sample are left out. Each sample is in
        exactly one block, except one logged at the same millisecond as the previous
        sample of its stream (the event model needs increasing times; site2 has none).

        Rotation rows gain ``w = sqrt(1 - x² - y² - z²)`` (clipped at 0), as Android's
        ``SensorManager.getQuaternionFromVector`` completes a three-value rotation vector.
        ``magnetic_calibrated`` is always true: a stream taken from uncalibrated records
        (see ``uncalibrated``) had the phone's hard-iron estimate subtracted on reading.

        Raises
        ------
        ValueError
            When ``block_ms`` is not positive.
        """
        if block_ms <= 0:
            raise ValueError(f"block_ms must be positive, not {block_ms}")
        motions = [self.accel, self.gyro, self.magnetic, self.rotation]
        if not motion:
            motions = [a[:0] for a in motions]
        accel, gyro, magnetic, rotation, pressure = (
            _increasing(a) for a in (*motions[:3], _with_scalar_part(motions[3]), self.pressure)
        )
        streams = (accel, gyro, magnetic, rotation, pressure)
        firsts = [a[0, 0] for a in streams if a.shape[0]]
        if not firsts:
            return []
        t0 = int(min(firsts))
        block_of = [(a[:, 0].astype(np.int64) - t0) // block_ms for a in streams]
        blocks = np.unique(np.concatenate(block_of))
        # piece i of a stream: its samples in blocks[i] (blocks[1:] are where pieces start)
        pieces = [
            np.split(a, np.searchsorted(b, blocks[1:]))
            for a, b in zip(streams, block_of, strict=True)
        ]
        return [
            ImuEvent(t0 + k * block_ms, accel=ac, gyro=gy, magnetic=ma, rotation=ro, pressure=pr)
            for k, ac, gy, ma, ro, pr in zip(blocks.tolist(), *pieces, strict=True)
        ]

    def events(
        self, imu: bool = False, block_ms: int = IMU_BLOCK_MS, pressure: bool = False
    ) -> list[Event]:
        """Radio events and, with ``imu``, the blocks of ``imu_events(block_ms)`` (with
        ``pressure`` alone, blocks of barometer samples only), sorted by time (stable: on a
        tie WiFi, then BLE, then the block).

        A block is placed at its start: a scan taken while its samples were logged comes
        after the whole block, as in a batch a phone posts.
        """
        events: list[Event] = [*self.radio_events()]
        if imu or pressure:
            events += self.imu_events(block_ms, motion=imu)
        events.sort(key=lambda e: e.t_ms)
        return events


def _with_scalar_part(rotation: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n, 4) ``[t, x, y, z]`` rotation-vector rows as (n, 5) ``[t, x, y, z, w]``."""
    w = np.sqrt(np.clip(1.0 - np.sum(rotation[:, 1:4] ** 2, axis=1), 0.0, None))
    return np.column_stack([rotation[:, :4], w])


def _increasing(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    """Time-sorted rows without those at the same time as the row before."""
    keep = np.ones(samples.shape[0], dtype=bool)
    keep[1:] = np.diff(samples[:, 0]) > 0
    return samples if keep.all() else samples[keep]


SENSORS = ("accel", "gyro", "magnetic", "rotation")


def _rows(parts: Sequence[NDArray[np.float64]], width: int) -> NDArray[np.float64]:
    rows = np.concatenate([p.reshape(-1, width) for p in parts]) if parts else np.empty((0, width))
    rows = rows[np.argsort(rows[:, 0], kind="stable")]
    # a sample sent twice (a retried batch) is kept once
    keep = np.ones(len(rows), dtype=bool)
    keep[1:] = np.diff(rows[:, 0]) > 0
    return np.ascontiguousarray(rows[keep])


def assemble_walk(
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
    parts: dict[str, list[NDArray[np.float64]]] = {name: [] for name in SENSORS}
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
    sensors = {name: _rows(parts[name], 4) for name in SENSORS}
    fixes = [
        (e.t_ms, e.lat_deg, e.lon_deg, e.accuracy_m, np.nan if e.hdop is None else e.hdop)
        for e in events
        if isinstance(e, GnssEvent)
    ]
    steps = [(e.t_ms, e.length_m, e.heading_rad) for e in events if isinstance(e, StepEvent)]
    return assemble_walk(
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
    sensors = {name: _rows([getattr(t, name) for t in traces], 4) for name in SENSORS}
    return assemble_walk(
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
