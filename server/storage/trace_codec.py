"""A recorded walk as bytes: one compressed array container (``storage.codec``: nothing
pickled; a corrupt blob raises ``CodecError``), how uploads in our own shape and the
batches a session offers for map building are kept."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from server.positioning.model.events import BleEvent, RadioReading, WifiEvent
from server.positioning.model.walk import SENSORS, Walk, assemble_walk
from server.storage.codec import array_to_str, compress_arrays, decompress_arrays, str_to_array

CONTENT_TYPE = "application/vnd.indoorpos.trace"


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
        **{name: getattr(trace, name) for name in SENSORS},
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
    return assemble_walk(
        path_id,
        array_to_str(a["floor"]),
        a["anchors"].reshape(-1, 3),
        wifi,
        ble,
        {name: a[name].reshape(-1, 4) for name in SENSORS},
        frozenset(marks.split(",")) if marks else frozenset(),
        a["gnss"].reshape(-1, 5) if "gnss" in a else np.empty((0, 5)),
        a["steps"].reshape(-1, 3) if "steps" in a else np.empty((0, 3)),
    )
