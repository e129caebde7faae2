"""The event model every engine consumes and the fix every engine produces.

Frames and units follow the service design: per building a local metric frame (x east,
y north, metres), floors by index into the site's floor list, headings in radians
clockwise from north (the y axis), RSS in dBm, magnetic field in µT, timestamps in
milliseconds since the epoch from the phone clock.

These are plain frozen dataclasses so the same values come out of the batch API, of the
dataset importers and of the simulator, and engines can be tested without any server.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True, slots=True)
class StepEvent:
    """A step detected on the phone."""

    t_ms: int
    length_m: float
    heading_rad: float  # clockwise from north
    confidence: float = 1.0


@dataclass(frozen=True, slots=True)
class RadioReading:
    """One emitter heard in a scan: ``emitter`` is the WiFi BSSID or the BLE beacon id;
    ``age_ms`` how long before the scan's time it was last heard (a cached reading is
    seconds old; None: fresh, or not known)."""

    emitter: str
    rssi_dbm: float
    age_ms: float | None = None


@dataclass(frozen=True, slots=True)
class WifiEvent:
    t_ms: int
    readings: tuple[RadioReading, ...]


@dataclass(frozen=True, slots=True)
class BleEvent:
    t_ms: int
    readings: tuple[RadioReading, ...]


@dataclass(frozen=True, slots=True)
class MagEvent:
    """Magnetometer reading: a vector in the phone frame, or only its magnitude."""

    t_ms: int
    field_ut: tuple[float, float, float] | None = None
    magnitude_ut: float | None = None

    @property
    def strength_ut(self) -> float:
        """The field magnitude: ``magnitude_ut``, else the vector's norm, else NaN."""
        if self.magnitude_ut is not None:
            return self.magnitude_ut
        if self.field_ut is not None:
            return math.hypot(*self.field_ut)
        return math.nan


def _no_samples(width: int) -> NDArray[np.float64]:
    return np.empty((0, width), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class ImuEvent:
    """A block of raw motion samples from the phone, each sensor at its own times.

    Every array has one row per sample, the sample time (ms since the epoch, phone clock)
    first and strictly increasing; a sensor the phone did not send has zero rows. Axes are
    the phone's (Android: x right, y towards the top edge, z out of the screen).

    ``t_ms`` is the start of the block: no sample in it is earlier.
    """

    t_ms: int
    accel: NDArray[np.float64] = field(default_factory=lambda: _no_samples(4))
    """[t_ms, x, y, z] specific force in m/s², gravity included."""
    gyro: NDArray[np.float64] = field(default_factory=lambda: _no_samples(4))
    """[t_ms, x, y, z] angular rate in rad/s (right-handed about each axis)."""
    magnetic: NDArray[np.float64] = field(default_factory=lambda: _no_samples(4))
    """[t_ms, x, y, z] magnetic field in µT."""
    magnetic_calibrated: bool = True
    """False when ``magnetic`` still holds the hard-iron bias (Android's uncalibrated)."""
    rotation: NDArray[np.float64] = field(default_factory=lambda: _no_samples(5))
    """[t_ms, x, y, z, w] unit quaternion of the phone in the east-north-up frame."""
    pressure: NDArray[np.float64] = field(default_factory=lambda: _no_samples(2))
    """[t_ms, hPa] barometric pressure."""

    @property
    def has_motion(self) -> bool:
        """Whether the block holds motion samples (anything but the barometer's)."""
        return any(a.shape[0] for a in (self.accel, self.gyro, self.magnetic, self.rotation))

    @property
    def t_end_ms(self) -> int:
        """Time of the latest sample of any sensor (``t_ms`` when there is none)."""
        ends = [a[-1, 0] for a in self.sensors().values() if a.shape[0]]
        return int(max(ends)) if ends else self.t_ms

    def sensors(self) -> dict[str, NDArray[np.float64]]:
        """The sample arrays by name."""
        return {
            "accel": self.accel,
            "gyro": self.gyro,
            "magnetic": self.magnetic,
            "rotation": self.rotation,
            "pressure": self.pressure,
        }


@dataclass(frozen=True, slots=True)
class GnssEvent:
    """A satellite fix: WGS-84 position, the phone's accuracy estimate and, where the
    phone reports it, the horizontal dilution of precision."""

    t_ms: int
    lat_deg: float
    lon_deg: float
    accuracy_m: float
    hdop: float | None = None


Event = StepEvent | WifiEvent | BleEvent | MagEvent | ImuEvent | GnssEvent


@dataclass(frozen=True, slots=True)
class Fix:
    """A position estimate.

    ``cov`` is the 2x2 position covariance in m² flattened row-major
    (xx, xy, yx, yy); ``floor`` is the index into the site's floor list. The radii that
    hold 68 % and 95 % of the errors and the probability of the floor are set by
    ``accuracy.calibrated`` (NaN before).
    """

    t_ms: int
    x_m: float
    y_m: float
    floor: int
    heading_rad: float | None
    cov: tuple[float, float, float, float]
    source: str  # what produced it: "step", "wifi", "ble"
    diagnostics: dict[str, float] = field(default_factory=dict)
    accuracy_68_m: float = math.nan
    accuracy_95_m: float = math.nan
    floor_prob: float = math.nan

    @property
    def uncertainty_m(self) -> float:
        """Root of the mean of the position variances: a 1-σ radius in metres."""
        return float(((self.cov[0] + self.cov[3]) / 2.0) ** 0.5)


BLE_WINDOW_MS = 2000
"""Span of one BLE scan when a recording lists every beacon advertisement on its own:
about the period of a WiFi scan (ILC site2: 2.0 s), so that one BLE fingerprint holds
what the phone heard of the beacons around it rather than one reading."""


def window_ble(events: Sequence[BleEvent], window_ms: int = BLE_WINDOW_MS) -> list[BleEvent]:
    """Beacon readings grouped into scans of ``window_ms`` phone time.

    A window starts at the first reading not yet in one and holds every reading up to
    ``window_ms`` later; it becomes one ``BleEvent`` stamped with its last reading's time
    (when the phone knows the whole scan), each beacon keeping its mean RSS over the
    window (advertisements of one beacon fluctuate by several dB; the mean is the
    estimate of its level there), to a quarter dB (exact in the float32 of the codecs).

    Parameters
    ----------
    events : sequence of BleEvent
        In any order; each may hold several readings.
    window_ms : int
        Positive.

    Returns
    -------
    list of BleEvent
        Time-ordered, one per window that heard at least one beacon.
    """
    if window_ms <= 0:
        raise ValueError(f"window_ms must be positive, not {window_ms}")
    out: list[BleEvent] = []
    start: int | None = None
    last = 0
    sums: dict[str, list[float]] = {}

    def close() -> None:
        if sums:
            readings = tuple(
                RadioReading(e, round(4.0 * s / n) / 4.0) for e, (s, n) in sorted(sums.items())
            )
            out.append(BleEvent(last, readings))
        sums.clear()

    for event in sorted(events, key=lambda e: e.t_ms):
        if start is None or event.t_ms > start + window_ms:
            close()
            start = event.t_ms
        last = event.t_ms
        for r in event.readings:
            if not math.isfinite(r.rssi_dbm):
                continue
            acc = sums.setdefault(r.emitter, [0.0, 0])
            acc[0] += r.rssi_dbm
            acc[1] += 1
    close()
    return out


def radio_key(kind: str, emitter: str) -> str:
    """The column key of an emitter in a radio map: ``"wifi:<bssid>"`` or ``"ble:<id>"``."""
    return f"{kind}:{emitter.lower()}"
