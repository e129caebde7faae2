"""What the dataset readers share: opening a text log, and scans gathered row by row."""

from __future__ import annotations

import lzma
import math
from collections.abc import Iterator
from pathlib import Path

from server.positioning.events import RadioReading


def open_text(path: Path) -> Iterator[str]:
    """Lines of a ``.txt`` or ``.xz`` file (undecodable bytes replaced, line ends kept)."""
    if path.suffix == ".xz":
        with lzma.open(path, "rt", encoding="utf-8", errors="replace", newline="") as f:
            yield from f
    else:
        with path.open(encoding="utf-8", errors="replace", newline="") as f:
            yield from f


def keep_strongest(scan: dict[str, float], emitter: str, rssi: float) -> None:
    """Record a reading of a scan being gathered; an emitter listed twice keeps its
    strongest reading."""
    if scan.get(emitter, -math.inf) < rssi:
        scan[emitter] = rssi


def readings(scan: dict[str, float]) -> tuple[RadioReading, ...]:
    """A gathered scan as readings."""
    return tuple(RadioReading(emitter, rssi) for emitter, rssi in scan.items())
