"""Per-device-model RSSI offsets of a building, and scans brought to the common level.

Phones of different models report the same signal a few dB apart (Li et al. name device
diversity a main cause of fingerprint mismatch). The contributions of a building carry
the device model of their upload (points surveyed through the admin API count as one
device, ``SURVEYED``; uploads that name none, ``UNKNOWN``); readings of different
devices in the same 1 m cell of a floor are co-located, and
``mapping.device_offsets.estimate_offsets`` finds each model's offset from them (their
reading-weighted mean is 0: the common level is the map's own mix).
A session that names its device model has that offset taken off its scans before the
engine sees them (``on_common_level``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import anyio
import numpy as np
from sqlalchemy.ext.asyncio import AsyncSession

from server.positioning.mapping.device_offsets import DeviceOffset, cell_ids, estimate_offsets
from server.positioning.model.events import BleEvent, Event, WifiEvent, radio_key
from server.storage.repositories import surveys as survey_repo

SURVEYED = "(surveyed)"  # device of points surveyed through the admin API
UNKNOWN = "(unknown)"  # device of uploads that did not name their model
CELL_M = 1.0  # co-located: the same 1 m cell of a floor (chosen on UJI training splits)


async def building_offsets(s: AsyncSession, building_id: str) -> dict[str, DeviceOffset]:
    """Offsets of the device models that contributed to the building's maps."""
    rows = await survey_repo.survey_readings_with_devices(s, building_id)
    if not rows:
        return {}
    floors = {f: i for i, f in enumerate(sorted({r[2] for r in rows}))}
    emitters: dict[str, int] = {}
    cells_xy, cells_floor, cell_of, emitter, rssi, device = [], [], [], [], [], []
    for x, y, floor_id, readings, upload_id, model in rows:
        cells_xy.append((x, y))
        cells_floor.append(floors[floor_id])
        for kind in ("wifi", "ble"):
            for key, value, *_ in readings.get(kind) or ():
                cell_of.append(len(cells_xy) - 1)
                emitter.append(emitters.setdefault(radio_key(kind, key), len(emitters)))
                rssi.append(float(value))
                device.append(model or (UNKNOWN if upload_id else SURVEYED))
    if not rssi:
        return {}

    def estimate() -> dict[str, DeviceOffset]:
        point_cell = cell_ids(np.array(cells_xy), np.array(cells_floor), CELL_M)
        return estimate_offsets(point_cell[np.array(cell_of)], emitter, rssi, device)

    return await anyio.to_thread.run_sync(estimate)


def on_common_level(events: Sequence[Event], offset_db: float | None) -> list[Event]:
    """The events with ``offset_db`` taken off every WiFi and BLE reading."""
    if not offset_db:
        return list(events)
    out: list[Event] = []
    for e in events:
        if isinstance(e, WifiEvent | BleEvent):
            readings = tuple(replace(r, rssi_dbm=r.rssi_dbm - offset_db) for r in e.readings)
            e = type(e)(e.t_ms, readings)
        out.append(e)
    return out
