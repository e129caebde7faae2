"""Synthetic WiFi access points and BLE beacons, and the RSS a phone hears from them.

Log-distance path loss with shadowing, for emitter ``j`` heard at ``p`` on level ``l``::

    rssi_j(p) = p0 + o_j - 10 n log10(max(d_j(p), 1 m)) - L_floor |l - l_j|
                - L_wall w_j(p) + s_j(p, l) + e,          e ~ N(0, sigma_scan^2)

- ``d_j`` the 3-D distance (levels ``floor_height_m`` apart), ``w_j`` the walls of the
  receiver's floor crossed by the straight line to the emitter (plan view);
- ``o_j ~ N(0, sigma_tx^2)`` a fixed offset per emitter (transmit power, antenna);
- ``s_j(p, l)`` a fixed shadowing field per emitter and level: a sum of ``K`` random plane
  waves with wavelengths in ``shadow_wavelength_m`` and standard deviation
  ``sigma_shadow``. Fixed means a survey can learn it; ``e`` is new at every scan;
- readings below the sensitivity are dropped (``NaN`` in arrays, absent on the wire).

Defaults (WiFi / BLE): ``p0`` -40 / -59 dBm at 1 m, ``n`` 2.8 / 2.5, floor loss 15 / 20
dB, wall loss 3 / 4 dB, ``sigma_tx`` 2 / 2 dB, ``sigma_shadow`` 3 / 3 dB, ``sigma_scan``
4 / 5 dB, sensitivity -95 / -95 dBm; levels 4 m apart. WiFi APs sit on a jittered grid
about 10 m apart on every floor, a few BLE beacons on walkable ground.

Only numpy; randomness through an ``rng: numpy.random.Generator`` argument.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from client_sim.building import SyntheticBuilding, count_crossings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
Kind = Literal["wifi", "ble"]

_SHADOW_WAVES = 8
_MAX_PAIRS = 2_000_000  # receiver x emitter x wall elements per vectorised slice


@dataclass(frozen=True, slots=True)
class PathLoss:
    """Parameters of the model in the module docstring."""

    p0_dbm: float = -40.0  # RSS at 1 m
    exponent: float = 2.8  # n
    floor_loss_db: float = 15.0  # per level between receiver and emitter
    wall_loss_db: float = 3.0  # per wall crossed; 0 turns walls off
    tx_sigma_db: float = 2.0  # sigma_tx, fixed per emitter
    shadow_sigma_db: float = 3.0  # sigma_shadow, fixed per emitter and place
    shadow_wavelength_m: tuple[float, float] = (4.0, 16.0)
    scan_sigma_db: float = 4.0  # sigma_scan, new at every scan
    sensitivity_dbm: float = -95.0
    floor_height_m: float = 4.0


WIFI = PathLoss()
BLE = PathLoss(p0_dbm=-59.0, exponent=2.5, floor_loss_db=20.0, wall_loss_db=4.0, scan_sigma_db=5.0)


@dataclass(frozen=True, eq=False)
class Emitters:
    """Emitters of one kind and what a phone hears from them.

    Attributes
    ----------
    kind : {"wifi", "ble"}
    ids : tuple of str
        BSSIDs (WiFi) or beacon ids (BLE), shape (n_emitters,).
    xy : ndarray, shape (n_emitters, 2)
    level : ndarray of int, shape (n_emitters,)
    offset_db : ndarray, shape (n_emitters,)
        Fixed per-emitter offset ``o_j``.
    wavevector : ndarray, shape (n_emitters, n_levels, K, 2)
        Shadowing plane waves (rad/m) per emitter and receiver level.
    phase : ndarray, shape (n_emitters, n_levels, K)
    levels : tuple of int
        Receiver levels the shadowing field is defined on.
    walls : tuple of ndarray, shape (n_walls, 2, 2)
        Walls of each of ``levels``.
    model : PathLoss
    """

    kind: Kind
    ids: tuple[str, ...]
    xy: FloatArray
    level: IntArray
    offset_db: FloatArray
    wavevector: FloatArray
    phase: FloatArray
    levels: tuple[int, ...]
    walls: tuple[FloatArray, ...]
    model: PathLoss

    def __len__(self) -> int:
        return len(self.ids)

    def mean_rssi_dbm(self, positions: FloatArray, level: int) -> FloatArray:
        """The fixed part of the RSS (everything but the scan noise, no sensitivity cut).

        Parameters
        ----------
        positions : ndarray, shape (n, 2)
        level : int
            Receiver level; must be one of ``levels``.

        Returns
        -------
        ndarray, shape (n, n_emitters)
        """
        m = self.model
        li = self.levels.index(level)
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        dz = (self.level - level).astype(np.float64)
        delta = p[:, None, :] - self.xy[None, :, :]
        d = np.sqrt(np.sum(delta * delta, axis=-1) + (dz * m.floor_height_m) ** 2)
        rssi = (
            m.p0_dbm
            + self.offset_db
            - 10.0 * m.exponent * np.log10(np.maximum(d, 1.0))
            - m.floor_loss_db * np.abs(dz)
        )
        if m.wall_loss_db:
            rssi = rssi - m.wall_loss_db * self._walls_crossed(p, self.walls[li])
        if m.shadow_sigma_db:
            k = self.wavevector[:, li]  # (m, K, 2)
            arg = np.einsum("nd,mkd->nmk", p, k) + self.phase[None, :, li, :]
            rssi = rssi + m.shadow_sigma_db * np.sqrt(2.0 / k.shape[1]) * np.cos(arg).sum(-1)
        out: FloatArray = rssi
        return out

    def scan(self, positions: FloatArray, level: int, rng: np.random.Generator) -> FloatArray:
        """One scan at each position: RSS in dBm, ``NaN`` where below the sensitivity.

        Parameters
        ----------
        positions : ndarray, shape (n, 2)
        level : int
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (n, n_emitters)
        """
        mean = self.mean_rssi_dbm(positions, level)
        rssi = mean + rng.normal(0.0, self.model.scan_sigma_db, size=mean.shape)
        rssi = np.minimum(np.round(rssi), 0.0)  # phones report whole dBm
        out: FloatArray = np.where(rssi >= self.model.sensitivity_dbm, rssi, np.nan)
        return out

    def readings(self, rssi_dbm: FloatArray) -> list[dict[str, Any]]:
        """One row of :meth:`scan` as wire readings (``bssid`` or ``id`` with ``rssi_dbm``)."""
        key = "bssid" if self.kind == "wifi" else "id"
        row = np.asarray(rssi_dbm, dtype=np.float64).reshape(-1)
        return [
            {key: self.ids[j], "rssi_dbm": float(row[j])} for j in np.flatnonzero(~np.isnan(row))
        ]

    def _walls_crossed(self, p: FloatArray, walls: FloatArray) -> FloatArray:
        n, m, w = len(p), len(self.ids), max(len(walls), 1)
        step = max(1, _MAX_PAIRS // (m * w))
        parts = [
            count_crossings(p[i : i + step, None, :], self.xy[None, :, :], walls)
            for i in range(0, n, step)
        ]
        counts: FloatArray = (
            np.concatenate(parts).astype(np.float64) if parts else np.zeros((0, m), np.float64)
        )
        return counts


@dataclass(frozen=True, eq=False)
class RadioEnvironment:
    """The WiFi access points and BLE beacons of one building."""

    wifi: Emitters
    ble: Emitters


def synthesize_radio(
    building: SyntheticBuilding,
    rng: np.random.Generator,
    *,
    ap_spacing_m: float = 10.0,
    beacons_per_floor: int = 4,
    wifi: PathLoss = WIFI,
    ble: PathLoss = BLE,
) -> RadioEnvironment:
    """Place WiFi APs on a jittered grid on every floor and BLE beacons on walkable
    ground; draw each emitter's fixed offset and shadowing field."""
    prefix = rng.integers(0, 256, size=3)
    ap_xy: list[FloatArray] = []
    ap_level: list[int] = []
    beacon_xy: list[FloatArray] = []
    beacon_level: list[int] = []
    for floor in building.floors:
        nx = max(1, round(building.width_m / ap_spacing_m))
        ny = max(1, round(building.depth_m / ap_spacing_m))
        cx = (np.arange(nx) + 0.5) * building.width_m / nx
        cy = (np.arange(ny) + 0.5) * building.depth_m / ny
        gx, gy = np.meshgrid(cx, cy, indexing="xy")
        grid = np.column_stack([gx.ravel(), gy.ravel()])
        jitter = rng.uniform(-0.3, 0.3, size=grid.shape) * [
            building.width_m / nx,
            building.depth_m / ny,
        ]
        ap_xy.append(grid + jitter)
        ap_level += [floor.level] * len(grid)
        if beacons_per_floor:
            candidates = floor.walkable_grid(1.0, wall_clearance_m=0.5)
            pick = rng.choice(len(candidates), size=beacons_per_floor, replace=False)
            beacon_xy.append(candidates[np.sort(pick)])
            beacon_level += [floor.level] * beacons_per_floor
    tag = "".join(f"{int(v):02x}" for v in prefix)
    bssids = tuple(
        f"02:{tag[0:2]}:{tag[2:4]}:{tag[4:6]}:{i >> 8:02x}:{i & 0xFF:02x}"
        for i in range(len(ap_level))
    )
    beacon_ids = tuple(f"sim-{tag}-{i:04d}" for i in range(len(beacon_level)))
    return RadioEnvironment(
        wifi=_emitters("wifi", bssids, _stack(ap_xy), ap_level, building, wifi, rng),
        ble=_emitters("ble", beacon_ids, _stack(beacon_xy), beacon_level, building, ble, rng),
    )


def _stack(parts: list[FloatArray]) -> FloatArray:
    out: FloatArray = np.concatenate(parts) if parts else np.zeros((0, 2), dtype=np.float64)
    return out


def _emitters(
    kind: Kind,
    ids: tuple[str, ...],
    xy: FloatArray,
    level: list[int],
    building: SyntheticBuilding,
    model: PathLoss,
    rng: np.random.Generator,
) -> Emitters:
    m, n_levels = len(ids), len(building.floors)
    lam = rng.uniform(*model.shadow_wavelength_m, size=(m, n_levels, _SHADOW_WAVES))
    angle = rng.uniform(0.0, 2.0 * np.pi, size=lam.shape)
    wavevector = (2.0 * np.pi / lam)[..., None] * np.stack([np.sin(angle), np.cos(angle)], -1)
    return Emitters(
        kind=kind,
        ids=ids,
        xy=xy,
        level=np.asarray(level, dtype=np.int64),
        offset_db=rng.normal(0.0, model.tx_sigma_db, size=m),
        wavevector=wavevector,
        phase=rng.uniform(0.0, 2.0 * np.pi, size=lam.shape),
        levels=building.levels,
        walls=tuple(f.walls for f in building.floors),
        model=model,
    )
