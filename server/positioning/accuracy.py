"""What a fix's uncertainty means: the radii that hold 68 % and 95 % of the errors.

An engine's own covariance is what its filter believes, and the filters believe too much
(they take fix after fix as independent while neighbouring scans share their errors).
Every fix therefore reports radii calibrated on recorded walks: with ``σ`` the root of
the mean of the engine's two position variances, ::

    accuracy_68_m = scale_68 · 1.5096 σ        accuracy_95_m = scale_95 · 2.4477 σ

where 1.5096 and 2.4477 are the radii of an isotropic 2-D Gaussian of standard deviation
``σ`` that hold 68 % and 95 % of it (``sqrt(-2 ln(1 - p))``), so that a scale of 1 trusts
the engine. The scales are each engine's defaults, chosen on the inner validation splits
of both development venues (``bench/accuracy.md``, "Calibrated uncertainty"): the
quantiles of the observed errors over those radii, never the test paths. Two scales,
because errors have heavier tails than a Gaussian: one covariance scale cannot make both
radii right. The reported covariance is the engine's times ``scale_68²`` (its 68 % circle
is ``accuracy_68_m``). Android reports the 68 % radius as a location's accuracy, the W3C
geolocation API the 95 % one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from server.positioning.events import Fix
from server.positioning.params import Params, Positive

R68 = math.sqrt(-2.0 * math.log(1.0 - 0.68))  # 1.5096: P(|e| <= R68 σ) = 68 % in 2-D
R95 = math.sqrt(-2.0 * math.log(1.0 - 0.95))  # 2.4477


@dataclass(frozen=True)
class AccuracyParams(Params):
    """Scales of the engine's own 68 % and 95 % radii (1: the engine's covariance as it
    is)."""

    scale_68: Positive = 1.0
    scale_95: Positive = 1.0


@dataclass(frozen=True)
class EngineParams(Params):
    """What every engine's parameters hold: how its fixes' uncertainty is reported."""

    accuracy: AccuracyParams = field(default_factory=AccuracyParams)


def calibrated(fix: Fix, params: AccuracyParams) -> Fix:
    """The fix with its 68 % and 95 % radii, its covariance scaled to the 68 % one and
    its floor probability (from ``diagnostics["floor_prob"]``, NaN where the engine gives
    none)."""
    sigma = fix.uncertainty_m
    c = params.scale_68**2
    return replace(
        fix,
        cov=(fix.cov[0] * c, fix.cov[1] * c, fix.cov[2] * c, fix.cov[3] * c),
        accuracy_68_m=params.scale_68 * R68 * sigma,
        accuracy_95_m=params.scale_95 * R95 * sigma,
        floor_prob=fix.diagnostics.get("floor_prob", math.nan),
    )
