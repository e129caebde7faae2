"""A synthetic indoor magnetic field: the Earth's field plus fixed anomalies from steel.

In the building frame (x east, y north, z up), on level ``l``::

    B(p, l) = B0 + a(p, l) + e,     e ~ N(0, sigma_read^2 I)

``B0`` is a uniform Earth field (default (1.5, 21, -43) µT: about 48 µT, dipping north
and down as in mid northern latitudes); ``a`` is fixed per level, each component a sum of
``K`` random plane waves with wavelengths in ``anomaly_wavelength_m`` (default 1.5-6 m)
and standard deviation ``anomaly_sigma_ut`` (default 4 µT) — fixed, so a survey learns
it; ``e`` is reading noise (default 0.5 µT).

Phones report the field in their own frame. :func:`to_phone_frame` turns a building-frame
vector into the frame of a phone held flat, screen up, its y axis along ``heading_rad``
(x to the right, z up); the magnitude, the vertical and the horizontal magnitude do not
depend on the heading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from client_sim.building import SyntheticBuilding

FloatArray = NDArray[np.float64]

_WAVES = 12


@dataclass(frozen=True, eq=False)
class MagneticField:
    """Attributes: ``base_ut`` (3,), ``wavevector`` (n_levels, 3, K, 2) rad/m, ``phase``
    (n_levels, 3, K), ``levels``, ``anomaly_sigma_ut``, ``noise_sigma_ut``."""

    base_ut: FloatArray
    wavevector: FloatArray
    phase: FloatArray
    levels: tuple[int, ...]
    anomaly_sigma_ut: float
    noise_sigma_ut: float

    def field_ut(self, positions: FloatArray, level: int) -> FloatArray:
        """Noise-free field in the building frame at each position.

        Parameters
        ----------
        positions : ndarray, shape (n, 2)
        level : int

        Returns
        -------
        ndarray, shape (n, 3)
        """
        li = self.levels.index(level)
        p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
        k = self.wavevector[li]  # (3, K, 2)
        arg = np.einsum("nd,ckd->nck", p, k) + self.phase[li][None]
        anomaly = self.anomaly_sigma_ut * np.sqrt(2.0 / k.shape[1]) * np.cos(arg).sum(-1)
        out: FloatArray = self.base_ut[None, :] + anomaly
        return out

    def sample(self, positions: FloatArray, level: int, rng: np.random.Generator) -> FloatArray:
        """One noisy reading in the building frame per position, shape (n, 3)."""
        mean = self.field_ut(positions, level)
        out: FloatArray = mean + rng.normal(0.0, self.noise_sigma_ut, size=mean.shape)
        return out


def synthesize_magnetic(
    building: SyntheticBuilding,
    rng: np.random.Generator,
    *,
    base_ut: tuple[float, float, float] = (1.5, 21.0, -43.0),
    anomaly_sigma_ut: float = 4.0,
    anomaly_wavelength_m: tuple[float, float] = (1.5, 6.0),
    noise_sigma_ut: float = 0.5,
) -> MagneticField:
    """Draw the fixed anomalies of every level of ``building``."""
    shape = (len(building.floors), 3, _WAVES)
    lam = rng.uniform(*anomaly_wavelength_m, size=shape)
    angle = rng.uniform(0.0, 2.0 * np.pi, size=shape)
    wavevector = (2.0 * np.pi / lam)[..., None] * np.stack([np.sin(angle), np.cos(angle)], -1)
    return MagneticField(
        base_ut=np.asarray(base_ut, dtype=np.float64),
        wavevector=wavevector,
        phase=rng.uniform(0.0, 2.0 * np.pi, size=shape),
        levels=building.levels,
        anomaly_sigma_ut=anomaly_sigma_ut,
        noise_sigma_ut=noise_sigma_ut,
    )


def to_phone_frame(field_ut: FloatArray, heading_rad: FloatArray | float) -> FloatArray:
    """Building-frame vectors, shape (n, 3), in the frame of a flat phone facing
    ``heading_rad`` (clockwise from north), shape (n,) or scalar: x right, y forward, z up."""
    b = np.asarray(field_ut, dtype=np.float64).reshape(-1, 3)
    h = np.broadcast_to(np.asarray(heading_rad, dtype=np.float64), (len(b),))
    s, c = np.sin(h), np.cos(h)
    out: FloatArray = np.column_stack(
        [b[:, 0] * c - b[:, 1] * s, b[:, 0] * s + b[:, 1] * c, b[:, 2]]
    )
    return out
