"""``fai_ekf``: Li et al.'s FAI-enhanced EKF (``papers/000_*`` section III-C, eq 28-38),
DR/WiFi and DR/BLE on the ``step_ekf`` filter.

The filter is ``step_ekf``'s (``[x, y, S, psi]``, phone steps, eq 32-38 are the EKF's
prediction and update); what changes is the noise of each WiFi/BLE position update,
``R = diag(eta^2, eta^2)`` (eq 29), with ``eta`` the scan's predicted error by the chosen
strategy (eq 31, ``FaiParams.strategy``):

* ``ct``: a constant, ``ct_m`` (6 m, section IV-C), the paper's baseline;
* ``ss``, ``sd``, ``wd``: one indicator (``server.positioning.fai``: signal strength,
  emitter geometry, weighted DSF), ``mc`` their linear combination (eq 26), ``mcm``
  (default) the largest of them (eq 27).

The fix is the engine's WKNN fix (as ``step_ekf``); the indicators are those of that fix:
SS of the scan's readings, SD of the heard emitters seen from the fix, WD of the reference
points the fix weighed, with their weights (the paper weighs its likelihood-selected points,
eq 24). An indicator that cannot be computed (no fitted emitter, no DSF) takes no part;
with none, or where the maps carry no indicator data (``SiteMaps.fai``), ``eta`` is
``ct_m``. ``eta^2`` is floored at ``min_fix_var_m2`` as every fix variance. With ``ct``
and ``ct_m^2`` equal to the learned variance the engine is ``step_ekf``.

Not here yet: DR/magnetic and DR/WiFi/magnetic (magnetic fingerprinting with its own
indicators, eq 20), and the crowdsourced reference points' location uncertainty of eq 9
(0: surveyed maps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from server.positioning import fai
from server.positioning.accuracy import AccuracyParams
from server.positioning.engines import radio_fusion as rf
from server.positioning.engines import step_ekf
from server.positioning.engines.base import EngineSpec
from server.positioning.fai import FaiParams
from server.positioning.sitemaps import SiteMaps


@dataclass(frozen=True)
class FaiEkfParams(step_ekf.StepEkfParams):
    """``step_ekf``'s parameters and the indicators'."""

    fai: FaiParams = field(default_factory=FaiParams)
    # not yet calibrated on its own (bench/accuracy.md): step_ekf's radii
    accuracy: AccuracyParams = field(default_factory=lambda: step_ekf.StepEkfParams().accuracy)


def fai_variance(
    m: rf.Matched, maps: SiteMaps, params: FaiEkfParams
) -> tuple[float, dict[str, float]]:
    """``eta^2`` of the scan's fix (module docstring) and the indicators as diagnostics."""
    p = params.fai
    eta, reported = p.ct_m, {}
    if p.strategy != "ct" and maps.fai is not None:
        found = m.whole
        ind = fai.indicators(
            maps.fai, m.scan, (found.x_m, found.y_m), found.neighbours, found.weights, p
        )
        chosen = ind.pick(p.strategy, p.ct_m)
        if math.isfinite(chosen):
            eta = chosen
        reported = {
            f"fai_{name}": value
            for name, value in (("ss", ind.ss), ("sd", ind.sd), ("wd", ind.wd))
            if math.isfinite(value)
        }
    reported["fai_eta_m"] = eta
    return max(eta**2, params.min_fix_var_m2), reported


def initial_state(params: FaiEkfParams) -> step_ekf.StepEkfState:
    return step_ekf.initial_state(params)


SPEC = EngineSpec(
    name="fai_ekf",
    params_type=FaiEkfParams,
    state_type=step_ekf.StepEkfState,
    initial_state=initial_state,
    run=step_ekf.runner(fai_variance),
    uses=frozenset({"step", "wifi", "ble"}),
)
