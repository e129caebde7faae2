"""The floor as an estimate of its own: a hidden Markov model over the site's floors.

A single scan's floor vote is often wrong (on ILC site2 the upper floors' scans voted
for another floor in long runs: every engine then had per-scan WKNN's floor hit rate).
The floor is therefore filtered over time, as a discrete Bayes filter over the floor
indices ``f = 0 .. n-1``:

* prediction over ``dt`` seconds: a person changes floor rarely, and to any floor
  alike (the map does not say where stairs and lifts are); after a long gap nothing is
  known any more::

      p'(f) = (1 - eps) p(f) + eps / n,   eps = 1 - exp(-rate * dt)

* update by a scan: ``p(f | scan) ∝ p'(f) L(scan | f)``, ``L`` from the scan's signal
  distances to each floor's reference points (``fingerprints.floor_log_likelihood``, the
  Gaussian RSS likelihood of ``papers/000_*`` eq 10-11 per floor); done inside
  ``fingerprints.wknn`` given the prediction as ``floor_log_prior``.

Log-probabilities are kept, normalised; an empty array means "nothing known yet" (a flat
prior).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy import special

FloatArray = NDArray[np.float64]


def logsumexp(a: FloatArray) -> float:
    """``scipy.special.logsumexp`` of a 1-D array, to the last bit.

    Where the largest entry is finite (no NaN, no ``+inf``, not all ``-inf``) this is
    scipy's own arithmetic -- the ``m`` entries at the maximum taken out of the sum, then
    ``log1p(s / m) + log(m) + max`` with ``s`` the sum of the others' ``exp(a - max)``
    -- in the same numpy operations on arrays of the same shapes (the tests compare the
    bits); anything else goes to scipy. scipy's array-API dispatch costs ~50 µs a call
    (scipy 1.17), several times what the floor filter and the scan's floor posterior
    compute with it.
    """
    if a.ndim != 1 or a.dtype != np.float64 or a.shape[0] == 0:
        return float(special.logsumexp(a))
    # the reductions as np.max and np.sum make them, without their Python wrappers
    top = np.maximum.reduce(a, keepdims=True)
    if not math.isfinite(top[0]):
        return float(special.logsumexp(a))
    at_top = a == top
    m = np.add.reduce(at_top, dtype=np.float64, keepdims=True)  # how many: exact
    s = np.add.reduce(np.exp(np.where(at_top, -np.inf, a) - top), keepdims=True)
    if s[0] != 0:
        s = s / m
    out = np.log1p(s) + np.log(m) + top
    if not math.isfinite(out[0]):  # scipy takes log(sum(exp(a))) then
        return float(special.logsumexp(a))
    return float(out[0])


def predict(logp: FloatArray, dt_s: float, rate_per_s: float) -> FloatArray:
    """The floor distribution ``dt_s`` seconds later (see the module docstring).

    Parameters
    ----------
    logp : ndarray, shape (n_floors,)
        Normalised log-probabilities; an empty array is returned as it is.
    dt_s : float
        Elapsed time; negative values count as 0.
    rate_per_s : float
        Floor changes per second (non-negative).

    Returns
    -------
    ndarray, shape (n_floors,)
        Normalised log-probabilities.
    """
    n = logp.shape[0]
    if n <= 1:
        return logp
    eps = 1.0 - math.exp(-rate_per_s * max(dt_s, 0.0))
    p = np.exp(logp - logsumexp(logp))
    p = (1.0 - eps) * p + eps / n
    out: FloatArray = np.log(np.maximum(p, 1e-300))
    return out - float(logsumexp(out))


def prior(logp: FloatArray, last_t_ms: int, t_ms: int, rate_per_s: float) -> FloatArray | None:
    """The prediction for a scan at ``t_ms`` after the last update at ``last_t_ms``; None
    when nothing is known yet (``logp`` empty)."""
    if logp.shape[0] == 0:
        return None
    return predict(logp, (t_ms - last_t_ms) / 1000.0, rate_per_s)


def shift(
    logp: FloatArray, floors: int, levels: NDArray[np.int64], groups: NDArray[np.int64]
) -> FloatArray:
    """The distribution after going ``floors`` floors up (negative: down), as the
    barometer saw it: the probability of floor index ``f`` moves to the floor of the same
    building (``groups``) whose level is ``levels[f] + floors``; floors with no such floor
    lose theirs. Unchanged when nothing is known or no floor has one to move to.
    """
    if logp.shape[0] == 0 or floors == 0:
        return logp
    out = np.full(logp.shape[0], -np.inf)
    index = {(int(g), int(v)): i for i, (g, v) in enumerate(zip(groups, levels, strict=True))}
    for f in range(logp.shape[0]):
        target = index.get((int(groups[f]), int(levels[f]) + floors))
        if target is not None:
            out[target] = np.logaddexp(out[target], logp[f])
    if not np.isfinite(out).any():
        return logp
    return np.maximum(out - float(logsumexp(out)), np.log(1e-300))
