"""``fai_ekf``: Li et al.'s FAI-enhanced EKF (``papers/000_*`` section III-C, eq 28-38),
DR/WiFi and DR/BLE on the ``step_ekf`` filter.

The filter is ``step_ekf``'s (``[x, y, S, psi]``, phone steps, eq 32-38 are the EKF's
prediction and update); what changes is the noise of each WiFi/BLE position update,
``R = diag(eta^2, eta^2)`` (eq 29), with ``eta`` the scan's predicted error by the chosen
strategy (eq 31, ``FaiParams.strategy``):

* ``ct``: a constant, ``ct_m`` (6 m, section IV-C), the paper's baseline;
* ``ss``, ``sd``, ``wd``: one indicator (``radio.accuracy_indicators``: signal strength,
  emitter geometry, weighted DSF), ``mc`` their linear combination (eq 26), ``mcm``
  (default) the largest of them (eq 27).

The fix is the engine's WKNN fix (as ``step_ekf``); the indicators are those of that fix:
SS of the scan's readings, SD of the heard emitters seen from the fix, WD of the reference
points the fix weighed, with their weights (the paper weighs its likelihood-selected points,
eq 24). An indicator that cannot be computed (no fitted emitter, no DSF) takes no part;
with none, or where the maps carry no indicator data (``SiteMaps.fai``), ``eta`` is
``ct_m``. ``eta^2`` is floored at ``min_fix_var_m2`` as every fix variance. With ``ct``
and ``ct_m^2`` equal to the learned variance the engine is ``step_ekf``.

DR/magnetic (``"mag"`` events, section III-A and the magnetic indicators): the field
magnitude measured between two steps is that step's, placed at the step's middle on the
dead-reckoned track (the filter's step length and heading). Every ``mag_steps`` steps
(10, the paper's short-term trajectory) the profile is matched inside a circle around
the last wireless fix carried along by dead reckoning, of ``mag_circle`` (3) times that
fix's predicted error (``server.positioning.magnetic.profile_matching``), and the match updates
the position with ``eta`` from ``strategy_mag`` (default MCM, CT 5 m) over the magnetic
SS and WD (SD needs field components a magnitude profile lacks), gated as the wireless
fixes. The profile then starts again (profiles do not overlap, so no two updates share a
step). With WiFi/BLE and a magnetic map both, this is the paper's DR/WiFi/magnetic
integration; without a magnetic map for the floor, or without magnetometer events,
DR/WiFi.

Not here: the crowdsourced reference points' location uncertainty of eq 9 (0: surveyed
maps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Self

import numpy as np
from numpy.typing import NDArray

from server.positioning.engines import step_ekf
from server.positioning.engines.shared import phone_steps, scan_fixes
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.engines.shared.spec import EngineSpec, on, on_mag, with_floor_changes
from server.positioning.filters.kalman import update
from server.positioning.magnetic import profile_matching
from server.positioning.model.accuracy import AccuracyParams
from server.positioning.model.events import BleEvent, Fix, MagEvent, StepEvent, WifiEvent
from server.positioning.model.state_codec import shape
from server.positioning.motion.barometer import FloorChange
from server.positioning.radio import accuracy_indicators
from server.positioning.radio.accuracy_indicators import FaiParams

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class FaiEkfParams(step_ekf.StepEkfParams):
    """``step_ekf``'s parameters and the indicators'."""

    fai: FaiParams = field(default_factory=FaiParams)
    # the radii that hold 68 % and 95 % of the errors (accuracy.py), chosen on the inner
    # validation splits of ILC site2 and the IPIN logs (bench/accuracy.md)
    accuracy: AccuracyParams = field(default_factory=lambda: AccuracyParams(0.80, 0.80, 1.60, 5.80))


def fai_variance(
    m: scan_fixes.Matched, maps: SiteMaps, params: FaiEkfParams
) -> tuple[float, dict[str, float]]:
    """``eta^2`` of the scan's fix (module docstring) and the indicators as diagnostics."""
    p = params.fai
    eta, reported = p.ct_m, {}
    found = scan_fixes.on_cells(maps, m, params) if p.strategy != "ct" else None
    if found is not None and maps.fai is not None:
        ind = accuracy_indicators.indicators(
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


def _no_rows() -> FloatArray:
    return np.zeros((0, 2))


@dataclass(frozen=True, kw_only=True)
class FaiEkfState(step_ekf.StepEkfState):
    """``step_ekf``'s state and the magnetic profile being gathered.

    Attributes
    ----------
    dr_xy : ndarray, shape (2,)
        Dead-reckoned position in the session's own frame (the sum of the filter's steps).
    mag_sum_ut, mag_count :
        Magnitudes measured since the last step: their sum and number.
    profile_xy : ndarray, shape (n, 2)
        The middle of each step of the profile on the dead-reckoned track, oldest first.
    profile_ut : ndarray, shape (n,)
        The mean magnitude measured before each of those steps.
    radio_offset : ndarray, shape (2,)
        The last wireless fix minus ``dr_xy`` at its time (NaN before any): the circle's
        centre is ``dr_xy + radio_offset``.
    radio_eta_m : float
        That fix's predicted error (NaN before any).
    """

    dr_xy: FloatArray = field(default_factory=lambda: np.zeros(2), metadata=shape(2))
    mag_sum_ut: float = 0.0
    mag_count: int = 0
    profile_xy: FloatArray = field(default_factory=_no_rows, metadata=shape(-1, 2))
    profile_ut: FloatArray = field(default_factory=lambda: np.zeros(0), metadata=shape(-1))
    radio_offset: FloatArray = field(default_factory=lambda: np.full(2, np.nan), metadata=shape(2))
    radio_eta_m: float = math.nan

    def with_field(self, t_ms: int, strength_ut: float) -> Self:
        """A magnetometer reading: its magnitude joins those of the step being walked."""
        del t_ms  # whenever measured, it belongs to the step being walked
        if not math.isfinite(strength_ut):
            return self
        return replace(self, mag_sum_ut=self.mag_sum_ut + strength_ut, mag_count=self.mag_count + 1)


def initial_state(params: FaiEkfParams) -> FaiEkfState:
    base = step_ekf.initial_state(params)
    return FaiEkfState(**{f: getattr(base, f) for f in base.__dataclass_fields__})


def _cleared(state: FaiEkfState) -> FaiEkfState:
    return replace(state, profile_xy=_no_rows(), profile_ut=np.zeros(0))


def _on_floor_change(
    state: FaiEkfState,
    change: FloorChange,
    maps: SiteMaps,
    params: FaiEkfParams,
    rng: np.random.Generator,
) -> tuple[FaiEkfState, Fix | None]:
    """A barometric floor change (``scan_fixes.on_floor_change``); on another floor the
    magnetic profile starts afresh, as after a scan's floor change."""
    new, _ = scan_fixes.on_floor_change(state, change, maps, params, rng)
    return (_cleared(new) if new.floor != state.floor else new), None


def _on_scan(
    state: FaiEkfState,
    event: WifiEvent | BleEvent,
    maps: SiteMaps,
    params: FaiEkfParams,
    rng: np.random.Generator,
) -> tuple[FaiEkfState, Fix | None]:
    """``step_ekf``'s scan update with the FAI noise; the fix (before fusion) and its
    predicted error become the magnetic search circle."""
    del rng  # deterministic
    used: list[tuple[scan_fixes.Matched, float]] = []

    def variance(
        m: scan_fixes.Matched, maps: SiteMaps, params: FaiEkfParams
    ) -> tuple[float, dict[str, float]]:
        var, reported = fai_variance(m, maps, params)
        used.append((m, reported["fai_eta_m"]))
        return var, reported

    new, fix = step_ekf.scan_update(state, event, maps, params, variance)
    assert isinstance(new, FaiEkfState)
    if not used:
        return new, fix
    restarted = not state.initialized or (
        fix is not None
        and ("reinitialised" in fix.diagnostics or "floor_change" in fix.diagnostics)
    )
    if restarted:  # the filter started (again, or on another floor): a new profile
        new = _cleared(new)
    m, eta = used[0]
    offset = np.array([m.whole.x_m, m.whole.y_m]) - new.dr_xy
    return replace(new, radio_offset=offset, radio_eta_m=eta), fix


def _on_step(
    state: FaiEkfState,
    event: StepEvent,
    maps: SiteMaps,
    params: FaiEkfParams,
    rng: np.random.Generator,
) -> tuple[FaiEkfState, Fix | None]:
    """``step_ekf``'s step; the step joins the profile with the magnitudes measured since
    the last one, and a full profile is matched (module docstring)."""
    new, fix = step_ekf.on_step(state, event, maps, params, rng)
    assert isinstance(new, FaiEkfState)
    if fix is None:  # no usable step, or no position yet
        return replace(new, mag_sum_ut=0.0, mag_count=0), fix
    step_m, psi = float(new.x[2]), float(new.x[3])
    dr = new.dr_xy + step_m * np.array([math.sin(psi), math.cos(psi)])
    new = replace(new, dr_xy=dr, mag_sum_ut=0.0, mag_count=0)
    steps = params.fai.mag_steps
    if steps == 0 or state.mag_count == 0:
        return _cleared(new) if steps == 0 else new, fix
    new = replace(
        new,
        # measured while walking the step: at its middle
        profile_xy=np.vstack([new.profile_xy, (state.dr_xy + dr)[None, :] / 2.0]),
        profile_ut=np.append(new.profile_ut, state.mag_sum_ut / state.mag_count),
    )
    if new.profile_ut.size < steps:
        return new, fix
    matched, mag_fix = _magnetic_update(new, maps, params, event.t_ms)
    return _cleared(matched), mag_fix or fix


def _magnetic_update(
    state: FaiEkfState, maps: SiteMaps, params: FaiEkfParams, t_ms: int
) -> tuple[FaiEkfState, Fix | None]:
    """Match the full profile and update the position with it (module docstring)."""
    p = params.fai
    grids = maps.magnetic.grids if maps.magnetic is not None else ()
    grid = grids[state.floor] if 0 <= state.floor < len(grids) else None
    if grid is None or not math.isfinite(state.radio_eta_m):
        return state, None
    centre = state.dr_xy + state.radio_offset
    found = profile_matching.match(
        grid,
        state.profile_xy - state.profile_xy[-1],
        state.profile_ut,
        (float(centre[0]), float(centre[1])),
        min(p.mag_circle * state.radio_eta_m, p.max_mag_radius_m),
        spacing_m=p.mag_spacing_m,
        kappa=p.kappa,
        kappa_d=p.kappa_d,
        alpha_ss=p.alpha_ss_mag,
    )
    if found is None:
        return state, None
    ind = accuracy_indicators.combine(found.ss_m, math.nan, found.wd_m, p)
    eta = ind.pick(p.strategy_mag, p.ct_mag_m)
    if not math.isfinite(eta):
        eta = p.ct_mag_m
    var_m2 = max(eta**2, params.min_fix_var_m2)
    # the profile ends halfway through the last step; the walker is at its end
    z = np.array([found.x_m, found.y_m]) + state.dr_xy - state.profile_xy[-1]
    u = update(state.x, state.P, z=z, H=step_ekf.H_POSITION, R=var_m2 * np.eye(2))
    diagnostics = {
        "fix_var_m2": var_m2,
        "fai_eta_m": eta,
        "mag_candidates": float(found.candidates),
        "mahalanobis2": u.mahalanobis2,
        **{
            f"fai_mag_{k}": v
            for k, v in (("ss", found.ss_m), ("wd", found.wd_m))
            if math.isfinite(v)
        },
    }
    if u.mahalanobis2 > params.gate_chi2:
        return state, None
    new = replace(state, x=u.x, P=u.P)
    return new, step_ekf.state_fix(new, t_ms, "mag", diagnostics)


# a batch in time order (stably); deterministic. One fix per step once initialised (the
# magnetic one where a profile matched) and one per accepted or re-initialising scan.
SPEC = EngineSpec(
    name="fai_ekf",
    params_type=FaiEkfParams,
    state_type=FaiEkfState,
    initial_state=initial_state,
    uses=phone_steps.USES | {"mag"},
    handlers=(*phone_steps.routes(_on_step, _on_scan, _on_floor_change), on(MagEvent, on_mag)),
    prepass=with_floor_changes,
)
