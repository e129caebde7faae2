"""What a fix's uncertainty means: the radii that hold 68 % and 95 % of the errors.

An engine's own covariance is what its filter believes, and the filters believe too much
(they take fix after fix as independent while neighbouring scans share their errors).
Every fix therefore reports radii calibrated on recorded walks: with ``σ`` the root of
the mean of the engine's two position variances and ``E`` the map's radio error (the
radius that held 68 % of the errors of radio fixes of held-out training paths on it,
``fix_error.FixErrorModel.error_68_m``), ::

    accuracy_68_m = sqrt((floor_68 · E)² + (scale_68 · 1.5096 σ)²)
    accuracy_95_m = sqrt((floor_95 · E)² + (scale_95 · 2.4477 σ)²)

where 1.5096 and 2.4477 are the radii of an isotropic 2-D Gaussian of standard deviation
``σ`` that hold 68 % and 95 % of it (``sqrt(-2 ln(1 - p))``), so that floors of 0 and
scales of 1 trust the engine. The floor stands for the errors the engine's covariance does
not see (the map's own: wrong reference points shared by neighbouring scans), which on
the development venues hardly follow ``σ`` (rank correlations of 0.0-0.4) but do follow
the map: measured in ``E``, one floor serves a mall whose radio fixes err 17 m, a museum
whose err 20 m and a campus whose err 8 m. The four values are each engine's defaults,
chosen on the inner validation splits of both development venues (``bench/accuracy.md``,
"Calibrated uncertainty"), never the test paths. Two radii, because errors have heavier
tails than a Gaussian: one covariance cannot make both right. The reported covariance is
the engine's scaled so that its 68 % circle is ``accuracy_68_m``. Android reports the 68 %
radius as a location's accuracy, the W3C geolocation API the 95 % one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Annotated

from annotated_types import Ge, Gt, Le

from server.positioning.model.events import Fix
from server.positioning.model.params import ParamError, Params

R68 = math.sqrt(-2.0 * math.log(1.0 - 0.68))  # 1.5096: P(|e| <= R68 σ) = 68 % in 2-D
R95 = math.sqrt(-2.0 * math.log(1.0 - 0.95))  # 2.4477


@dataclass(frozen=True)
class AccuracyParams(Params):
    """Floors (in the map's radio error ``E``) and scales of the engine's own 68 % and
    95 % radii (0 and 1: the engine's covariance as it is)."""

    floor_68: Annotated[float, Ge(0), Le(20)] = 0.0
    scale_68: Annotated[float, Gt(0), Le(100)] = 1.0
    floor_95: Annotated[float, Ge(0), Le(20)] = 0.0
    scale_95: Annotated[float, Gt(0), Le(100)] = 1.0

    def check(self) -> None:
        """The 95 % radius is never the smaller one."""
        if self.floor_95 < self.floor_68:
            raise ParamError("floor_95", "must not be below floor_68")
        if self.scale_95 * R95 < self.scale_68 * R68:
            raise ParamError("scale_95", f"must be at least scale_68 x {R68 / R95:.4f}")

    def radii(self, sigma_m: float, error_68_m: float) -> tuple[float, float]:
        """The 68 % and 95 % radii of a fix whose own 1-σ is ``sigma_m`` on a map whose
        radio error is ``error_68_m``."""
        return (
            math.hypot(self.floor_68 * error_68_m, self.scale_68 * R68 * sigma_m),
            math.hypot(self.floor_95 * error_68_m, self.scale_95 * R95 * sigma_m),
        )


@dataclass(frozen=True)
class EngineParams(Params):
    """What every engine's parameters hold: how its fixes' uncertainty is reported."""

    accuracy: AccuracyParams = field(default_factory=AccuracyParams)


def calibrated(fix: Fix, params: AccuracyParams, error_68_m: float) -> Fix:
    """The fix with its 68 % and 95 % radii on a map whose radio error is ``error_68_m``,
    its covariance scaled to the 68 % one and its floor probability (from
    ``diagnostics["floor_prob"]``, NaN where the engine gives none)."""
    sigma = fix.uncertainty_m
    r68, r95 = params.radii(sigma, error_68_m)
    var = (r68 / R68) ** 2  # the mean variance of the reported covariance
    mean_var = (fix.cov[0] + fix.cov[3]) / 2.0
    if mean_var > 1e-9 * var:
        c = var / mean_var
        cov = (fix.cov[0] * c, fix.cov[1] * c, fix.cov[2] * c, fix.cov[3] * c)
    else:  # the engine claims certainty: a round covariance of the 68 % radius
        cov = (var, 0.0, 0.0, var)
    return replace(
        fix,
        cov=cov,
        accuracy_68_m=r68,
        accuracy_95_m=r95,
        floor_prob=fix.diagnostics.get("floor_prob", math.nan),
    )
