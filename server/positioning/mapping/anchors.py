"""Outer anchor nodes along a crowdsourced trace (``papers/003_*`` section IV-B).

Outer anchors (ANs) are places where a trace's true position is known without a floor
plan; they bound the closed segments that are aligned (IV-C) and gridded into maps.

GNSS anchors
------------
"GNSS data with position accuracy higher than 5.0 m and horizontal dilution of precision
(HDOP) less than 20 were considered qualified" (IV-B). A fix qualifies when::

    accuracy_m < 5.0   and   hdop < 20

(the phone's reported accuracy radius, so "higher accuracy" is a smaller number; a NaN
accuracy or HDOP, i.e. not reported, does not qualify). A qualified fix becomes a point
of the building frame (x east, y north before rotation, metres; DESIGN.md "Frames")
through the building's geo-reference ``(φ0, λ0, θ)``: origin latitude and longitude and
the bearing ``θ`` of the building's y axis, clockwise from north. With the
equirectangular approximation (error well under a centimetre over a building's extent)
and the IUGG mean Earth radius ``R = 6 371 008.8 m``::

    e = R (λ - λ0) cos φ0,        n = R (φ - φ0)          (angles in radians,
                                                             λ - λ0 wrapped to ±π)
    x = e cos θ - n sin θ,        y = e sin θ + n cos θ

so that the unit vector along the bearing ``θ``, ``(e, n) = (sin θ, cos θ)``, maps to
``(0, 1)``. 0.001° of latitude is ``R π / 180 × 0.001 = 111.19 m``.

BLE anchors
-----------
"An average filter was first applied to smooth the raw RSS data; subsequently, a
sliding window was used to detect the RSS peak when the user traversed the beacon
coverage area. Finally, when RSS peak exceeded a certain threshold [...] the position of
BLE AN (i.e., elevator location) was updated the user location" (IV-B, Fig. 6). Per
known beacon, over its readings ``(t_i, r_i)`` in time order:

* average filter: ``r̄_i = mean { r_j : |t_j - t_i| <= smooth_ms / 2 }`` (a time window,
  so scans the beacon was missing from do not stretch it; 2 s is about 7 scans at the
  paper's 300 ms BLE scan interval, VI-A);
* peaks: ``scipy.signal.find_peaks`` on ``r̄`` with ``height = threshold_dbm`` (the
  "certain threshold"; the paper gives no number, we use the -65 dBm of floor-plan
  anchors, ``server.positioning.plan.anchors.DEFAULT_RSSI_DBM``) and a prominence of
  ``min_prominence_db`` against noise wiggles on a plateau;
* sliding window: of peaks closer than ``peak_window_ms`` in time only the highest is
  kept, so one pass by the beacon gives one anchor;
* ends: the series is padded with a low value at both ends, so a trace that starts or
  ends beside a beacon (inside the elevator) has its peak at the first or last reading.

The anchor is at the time of the smoothed peak and at the beacon's known position and
floor. ``smooth_ms``, ``min_prominence_db`` and ``peak_window_ms`` are ours.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.signal import find_peaks

from server.positioning.model.geo import GeoReference
from server.positioning.plan.anchors import DEFAULT_RSSI_DBM

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

EARTH_RADIUS_M = 6_371_008.8  # IUGG mean radius


# ---------------------------------------------------------------- GNSS


def geo_to_local(lat_deg: ArrayLike, lon_deg: ArrayLike, ref: GeoReference) -> FloatArray:
    """Latitude/longitude to the building frame (module docstring formula).

    Parameters
    ----------
    lat_deg, lon_deg : array_like, shape (n,)
        WGS84 degrees.
    ref : GeoReference

    Returns
    -------
    ndarray, shape (n, 2)
        ``(x, y)`` in metres.
    """
    lat = np.asarray(lat_deg, dtype=np.float64).reshape(-1)
    lon = np.asarray(lon_deg, dtype=np.float64).reshape(-1)
    if lat.shape != lon.shape:
        raise ValueError(f"lon_deg must have shape {lat.shape}, got {lon.shape}")
    dlon = np.radians((lon - ref.origin_lon_deg + 180.0) % 360.0 - 180.0)
    east = EARTH_RADIUS_M * dlon * math.cos(math.radians(ref.origin_lat_deg))
    north = EARTH_RADIUS_M * np.radians(lat - ref.origin_lat_deg)
    c, s = math.cos(ref.rotation_rad), math.sin(ref.rotation_rad)
    return np.column_stack([east * c - north * s, east * s + north * c])


@dataclass(frozen=True)
class GnssAnchors:
    """Qualified GNSS fixes as anchors, and what was left out.

    Attributes
    ----------
    t_ms : ndarray, shape (k,), int64
    xy_m : ndarray, shape (k, 2), float64
        Building frame.
    source : ndarray, shape (k,), int64
        Row of each anchor in the ``fixes`` given.
    n_fixes : int
    n_bad_accuracy : int
        Fixes with ``accuracy_m >= max_accuracy_m`` or no accuracy.
    n_bad_hdop : int
        Fixes with ``hdop >= max_hdop`` or no HDOP (a fix can count in both).
    """

    t_ms: IntArray
    xy_m: FloatArray
    source: IntArray
    n_fixes: int
    n_bad_accuracy: int
    n_bad_hdop: int


def gnss_anchors(
    fixes: ArrayLike,
    ref: GeoReference,
    *,
    max_accuracy_m: float = 5.0,  # IV-B: "position accuracy higher than 5.0 m"
    max_hdop: float = 20.0,  # IV-B: "HDOP less than 20"
) -> GnssAnchors:
    """GNSS fixes that qualify as outer anchors, in the building frame (IV-B).

    Parameters
    ----------
    fixes : array_like, shape (n, 5)
        Rows ``[t_ms, lat_deg, lon_deg, accuracy_m, hdop]``; accuracy and HDOP may be
        NaN when the phone did not report them.
    ref : GeoReference
    max_accuracy_m, max_hdop : float
        A fix qualifies when ``accuracy_m < max_accuracy_m`` and ``hdop < max_hdop``.

    Returns
    -------
    GnssAnchors
        Qualified fixes in input order.
    """
    arr = np.asarray(fixes, dtype=np.float64)
    if arr.size == 0:
        arr = arr.reshape(0, 5)
    if arr.ndim != 2 or arr.shape[1] != 5:
        raise ValueError(f"fixes must have shape (n, 5), got {arr.shape}")
    if not np.all(np.isfinite(arr[:, :3])):
        raise ValueError("fixes must have finite t_ms, lat_deg, lon_deg")
    if np.any(np.abs(arr[:, 1]) > 90.0) or np.any(np.abs(arr[:, 2]) > 180.0):
        raise ValueError("fixes must have lat_deg in [-90, 90] and lon_deg in [-180, 180]")
    good_accuracy = arr[:, 3] < max_accuracy_m  # NaN (not reported) compares False
    good_hdop = arr[:, 4] < max_hdop
    ok = np.flatnonzero(good_accuracy & good_hdop)
    return GnssAnchors(
        t_ms=arr[ok, 0].astype(np.int64),
        xy_m=geo_to_local(arr[ok, 1], arr[ok, 2], ref),
        source=ok.astype(np.int64),
        n_fixes=int(arr.shape[0]),
        n_bad_accuracy=int(np.count_nonzero(~good_accuracy)),
        n_bad_hdop=int(np.count_nonzero(~good_hdop)),
    )


# ---------------------------------------------------------------- BLE

Beacon = tuple[str, ArrayLike, int]  # (id, (x_m, y_m), floor)


@dataclass(frozen=True)
class BleAnchors:
    """Passes by known beacons found along a trace.

    Attributes
    ----------
    t_ms : ndarray, shape (k,), int64
        Time of the smoothed RSS peak, in time order.
    xy_m : ndarray, shape (k, 2), float64
        The beacon's known position.
    floor : ndarray, shape (k,), int64
    beacon : ndarray, shape (k,), int64
        Index into the ``beacons`` given.
    peak_dbm : ndarray, shape (k,), float64
        Smoothed RSS at the peak.
    n_unknown : int
        Readings of beacons not in ``beacons`` (ignored).
    """

    t_ms: IntArray
    xy_m: FloatArray
    floor: IntArray
    beacon: IntArray
    peak_dbm: FloatArray
    n_unknown: int


def _smooth(t: FloatArray, r: FloatArray, half_ms: float) -> FloatArray:
    """Mean of the readings within ``±half_ms`` of each reading (``t`` sorted)."""
    csum = np.concatenate([[0.0], np.cumsum(r)])
    lo = np.searchsorted(t, t - half_ms, side="left")
    hi = np.searchsorted(t, t + half_ms, side="right")
    return np.asarray((csum[hi] - csum[lo]) / (hi - lo), dtype=np.float64)


def _highest_apart(t: FloatArray, height: FloatArray, window_ms: float) -> IntArray:
    """Of peaks closer than ``window_ms``, keep the highest (greedy, highest first)."""
    kept: list[int] = []
    for i in np.argsort(-height, kind="stable"):
        if all(abs(t[i] - t[j]) >= window_ms for j in kept):
            kept.append(int(i))
    return np.sort(np.array(kept, dtype=np.int64))


def ble_anchors(
    t_ms: ArrayLike,
    beacon_id: Sequence[str],
    rssi_dbm: ArrayLike,
    beacons: Sequence[Beacon],
    *,
    threshold_dbm: float = DEFAULT_RSSI_DBM,
    smooth_ms: float = 2000.0,
    min_prominence_db: float = 3.0,
    peak_window_ms: float = 10_000.0,
) -> BleAnchors:
    """Times and places a trace passed known BLE beacons (IV-B, module docstring).

    Parameters
    ----------
    t_ms : array_like, shape (m,)
        Time of each BLE reading, ms.
    beacon_id : sequence of str, length m
        Beacon heard in each reading.
    rssi_dbm : array_like, shape (m,)
        RSS of each reading, dBm.
    beacons : sequence of (id, (x_m, y_m), floor)
        The known beacons (elevators, entrances) with their positions in the building
        frame.
    threshold_dbm : float
        A smoothed peak must reach this RSS.
    smooth_ms : float
        Width of the average filter's time window.
    min_prominence_db : float
        Prominence a peak needs (``scipy.signal.find_peaks``).
    peak_window_ms : float
        Of peaks of one beacon closer than this, only the highest counts.

    Returns
    -------
    BleAnchors
    """
    t = np.asarray(t_ms, dtype=np.float64).reshape(-1)
    r = np.asarray(rssi_dbm, dtype=np.float64).reshape(-1)
    ids = list(beacon_id)
    if not np.all(np.isfinite(t)):
        raise ValueError("t_ms must be finite")
    if len(ids) != t.size:
        raise ValueError(f"beacon_id must have length {t.size}, got {len(ids)}")
    if r.shape != t.shape:
        raise ValueError(f"rssi_dbm must have shape {t.shape}, got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError("rssi_dbm must be finite")
    if not (smooth_ms >= 0 and min_prominence_db >= 0 and peak_window_ms >= 0):
        raise ValueError("smooth_ms, min_prominence_db and peak_window_ms must be >= 0")
    index: dict[str, int] = {}
    xy = np.zeros((len(beacons), 2))
    floors = np.zeros(len(beacons), dtype=np.int64)
    for b, (bid, pos, floor) in enumerate(beacons):
        p = np.asarray(pos, dtype=np.float64).reshape(-1)
        if bid in index:
            raise ValueError(f"beacons lists {bid!r} twice")
        if p.shape != (2,) or not np.all(np.isfinite(p)):
            raise ValueError(f"beacons: position of {bid!r} must be 2 finite numbers")
        index[bid], xy[b], floors[b] = b, p, int(floor)

    which = np.array([index.get(i, -1) for i in ids], dtype=np.int64)
    found_t: list[FloatArray] = []
    found_b: list[IntArray] = []
    found_r: list[FloatArray] = []
    for b in np.unique(which[which >= 0]):
        sel = np.flatnonzero(which == b)
        sel = sel[np.argsort(t[sel], kind="stable")]
        tb = t[sel]
        smooth = _smooth(tb, r[sel], smooth_ms / 2.0)
        # a low sample at each end, so a trace starting or ending at a beacon has a peak
        pad = float(smooth.min()) - min_prominence_db - 1.0
        padded = np.concatenate([[pad], smooth, [pad]])
        peaks, _ = find_peaks(padded, height=threshold_dbm, prominence=min_prominence_db)
        peaks = np.asarray(peaks, dtype=np.int64) - 1
        peaks = peaks[_highest_apart(tb[peaks], smooth[peaks], peak_window_ms)]
        found_t.append(tb[peaks])
        found_b.append(np.full(peaks.size, b, dtype=np.int64))
        found_r.append(smooth[peaks])

    at = np.concatenate([np.empty(0), *found_t])
    bb = np.concatenate([np.empty(0, dtype=np.int64), *found_b])
    pk = np.concatenate([np.empty(0), *found_r])
    order = np.argsort(at, kind="stable")
    bb = bb[order]
    return BleAnchors(
        t_ms=np.round(at[order]).astype(np.int64),
        xy_m=xy[bb].reshape(-1, 2),
        floor=floors[bb],
        beacon=bb,
        peak_dbm=pk[order],
        n_unknown=int(np.count_nonzero(which < 0)),
    )
