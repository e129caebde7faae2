"""What the dataset readers share: opening a text log, naming it, scans gathered row by row,
and the report of what a reader could not read."""

from __future__ import annotations

import lzma
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from server.positioning.model.events import RadioReading


@dataclass(frozen=True)
class ParseReport:
    """What a reader met in a file besides the walk it read.

    Attributes
    ----------
    bad_lines : int
        Records (lines) dropped because they could not be read.
    joined_lines : int
        Lines that held several records run together (their records were read; ILC).
    stale_wifi_readings : int
        WiFi rows dropped as older than the reader's limit at their scan time (ILC).
    skipped_types : Mapping of str to int
        Records of types the reader does not read, per type.
    """

    bad_lines: int = 0
    joined_lines: int = 0
    stale_wifi_readings: int = 0
    skipped_types: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))


def open_text(path: Path) -> Iterator[str]:
    """Lines of a ``.txt`` or ``.xz`` file (undecodable bytes replaced, line ends kept)."""
    if path.suffix == ".xz":
        with lzma.open(path, "rt", encoding="utf-8", errors="replace", newline="") as f:
            yield from f
    else:
        with path.open(encoding="utf-8", errors="replace", newline="") as f:
            yield from f


def file_id(path: Path) -> str:
    """A recording's name: its file name without ``.txt`` / ``.txt.xz``."""
    name = path.name
    for suffix in (".xz", ".txt"):
        name = name.removesuffix(suffix)
    return name


def keep_strongest(scan: dict[str, float], emitter: str, rssi: float) -> None:
    """Record a reading of a scan being gathered; an emitter listed twice keeps its
    strongest reading."""
    if scan.get(emitter, -math.inf) < rssi:
        scan[emitter] = rssi


def readings(
    scan: dict[str, float], age_ms: Mapping[str, float] | None = None
) -> tuple[RadioReading, ...]:
    """A gathered scan as readings, with each reading's age where ``age_ms`` has it."""
    ages = age_ms or {}
    return tuple(RadioReading(emitter, rssi, ages.get(emitter)) for emitter, rssi in scan.items())
