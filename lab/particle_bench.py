"""Timing of the particle filter: mass-centered against DTW weight update, and state size.

``papers/001_*`` section IV-B (Figure 12) reports the mass-centered update 18 times
faster than the DTW of the Magicol baseline at ``N = 3000``, without saying what the
timed code contained. Measured here, in one process and on the same inputs:

* **Update** (the headline): one call of ``particle_weight_update.mass_centered_update``
  or ``particle_weight_update.dtw_update`` -- map magnitudes sampled at every particle,
  windows shifted, the sequence distance of every particle over its ``W + 1`` magnitudes,
  the award of eq (c) and the normalisation. The inputs are the moved clouds of a
  recorded walk, each with full windows, and the magnitude the phone measured at that step.
* **Distance**: eq (b) on those windows against the DTW of the same windows sampled as
  the baseline samples them (``dtw_samples_per_step`` per step,
  ``sequence_distance.densified``), both compiled (``magnetic_kernels.mmse``,
  ``magnetic_kernels.dtw``): the only part that differs between the two updates.
* **Filter step**: a whole step -- move with the floor plan's wall test, update,
  resampling when ``N_eff`` is low -- from the clouds of the same walk, as the engine
  runs it: ``particle.step_on_floor`` (one compiled pass) for the mass-centered filter,
  ``particle.step`` for the DTW one; and the mass-centered step in numpy alone
  (``particle.step`` with ``compiled=False`` and the numpy wall test and map sampling),
  the reference the compiled step is tested against (``compiled_speedup``).
* **State**: the cloud as the session store keeps it: ``state_codec.to_arrays`` then
  ``codec.encode_arrays`` (``state_bytes`` is that blob's length, ``encode_us`` the
  time of both), and back through ``codec.decode_arrays`` and ``state_codec.from_arrays``
  (``decode_us``).

The site is synthetic and fixed: a 60 m x 3 m corridor (the paper's testbed is a 60 m x
40 m floor of corridors) with a magnetic field made of a few sines and bumps around 45 µT
on the 0.5 m grid of the project's maps. The particles start spread over the whole
corridor; the phone walks east at 0.7 m per step. Every rate is a median over
``repeat`` runs; in each run the methods alternate, so both see the same machine state.
Ratios, not absolute rates, are what carries over to another machine.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from server.positioning.filters import (
    particle,
    particle_move,
    particle_resampling,
    particle_weight_update,
)
from server.positioning.filters import particle_cloud as pc
from server.positioning.magnetic import magnetic_kernels
from server.positioning.magnetic.field_grid import MagneticGrid, _bilinear, sample
from server.positioning.magnetic.sequence_distance import densified
from server.positioning.mapping.magnetic_gridding import grid_from_samples
from server.positioning.model import state_codec
from server.positioning.plan.floor_plan import (
    FloorPlan,
    valid_moves,
    valid_moves_reference,
    walkable_at,
)
from server.positioning.plan.geojson_plan import plan_from_geojson
from server.storage.codec import decode_arrays, encode_arrays

CORRIDOR_M = (60.0, 3.0)  # length along x, width along y
STEP_M = 0.7
N_INPUTS = 16  # recorded steps every timing cycles through
MIN_RUN_S = 0.02  # each timed run lasts at least this long (whole passes over the inputs)


@dataclass(frozen=True)
class _Walk:
    """Recorded inputs: per step the cloud before it, the step and the measured field."""

    before: tuple[pc.Particles, ...]  # clouds before ``move``
    moved: tuple[pc.Particles, ...]  # the same after ``move`` (update inputs)
    observed_ut: tuple[float, ...]
    heading_rad: float


def particle_bench(
    n_particles: int = 3000,
    *,
    window: int = 3,
    repeat: int = 15,
    seed: int = 0,
    min_run_s: float = MIN_RUN_S,
    dtw_samples_per_step: int | None = None,
) -> dict[str, Any]:
    """Time both weight updates, both filter steps and the state codec.

    Parameters
    ----------
    n_particles : int
        Particle count ``N`` (the paper: 3,000).
    window : int
        Window ``W`` in steps (the paper: 3).
    repeat : int
        Timed runs per measure; the median is reported.
    seed : int
        Seed of the walk (initial cloud, motion noise, phone noise).
    min_run_s : float
        Shortest timed run (s): a run repeats whole passes over the recorded steps, as
        many as the warm-up pass says it takes to last this long.
    dtw_samples_per_step : int, optional
        The DTW baseline's samples per step (default: ``ParticleParams``' own).

    Returns
    -------
    dict
        ``particles, window, repeat, mass_centered_steps_per_s, dtw_steps_per_s,
        speed_ratio`` (mass-centered / DTW updates per second), ``mmse_per_s,
        dtw_distance_per_s, distance_speed_ratio``, ``mass_centered_filter_steps_per_s,
        dtw_filter_steps_per_s, filter_speed_ratio``, ``numpy_filter_steps_per_s,
        compiled_speedup`` (compiled / numpy mass-centered steps per second),
        ``dtw_samples_per_step``, ``state_bytes, encode_us, decode_us``.
    """
    if repeat < 1:
        raise ValueError(f"repeat must be at least 1, got {repeat}")
    params = pc.ParticleParams(n=n_particles, window=window)
    if dtw_samples_per_step is not None:
        params = replace(params, dtw_samples_per_step=dtw_samples_per_step)
    per_step = params.dtw_samples_per_step
    plan, grid = _corridor(seed)

    def sample_map(_floor: pc.FloorArray, xy: particle.FloatArray) -> particle.FloatArray:
        return sample(grid, xy)

    def valid_move(
        _floor: pc.FloorArray, a: particle.FloatArray, b: particle.FloatArray
    ) -> particle.BoolArray:
        return valid_moves(plan, a, b)

    walk = _record_walk(plan, grid, params, seed, sample_map, valid_move)
    pairs = list(zip(walk.moved, walk.observed_ut, strict=True))
    updated = [
        particle_weight_update.mass_centered_update(q, o, sample_map, params) for q, o in pairs
    ]
    # full windows (the walk skipped W steps), as each distance takes them
    windows = [(p.observed.astype(np.float64), p.mags.astype(np.float64)) for p in updated]
    sampled = [(densified(o, per_step), densified(m, per_step)) for o, m in windows]

    def update(fn: Callable[..., pc.Particles]) -> Callable[[], object]:
        return lambda: [fn(q, o, sample_map, params) for q, o in pairs]

    def distance(fn: Callable[..., object], inputs: list[Any]) -> Callable[[], object]:
        return lambda: [fn(obs, mags) for obs, mags in inputs]

    steps = list(zip(walk.before, walk.observed_ut, strict=True))

    def filter_step(weighting: pc.Weighting) -> Callable[[], object]:
        rng = np.random.default_rng([seed, 2])
        if weighting == "mass_centered":  # as the engine runs it
            return lambda: [
                particle.step_on_floor(p, STEP_M, walk.heading_rad, o, rng, params, plan, grid)
                for p, o in steps
            ]
        return lambda: [
            particle.step(
                p, STEP_M, walk.heading_rad, o, rng, params, valid_move, sample_map, weighting
            )
            for p, o in steps
        ]

    def numpy_step() -> Callable[[], object]:
        rng = np.random.default_rng([seed, 2])

        def numpy_move(
            _f: pc.FloorArray, a: particle.FloatArray, b: particle.FloatArray
        ) -> particle.BoolArray:
            return valid_moves_reference(plan, a, b)

        def numpy_map(_f: pc.FloorArray, xy: particle.FloatArray) -> particle.FloatArray:
            return _bilinear(grid, xy, "magnitude")

        return lambda: [
            particle.step(
                p,
                STEP_M,
                walk.heading_rad,
                o,
                rng,
                params,
                numpy_move,
                numpy_map,
                compiled=False,
            )
            for p, o in steps
        ]

    n = len(pairs)
    mc, dtw = _rates(
        [
            update(particle_weight_update.mass_centered_update),
            update(particle_weight_update.dtw_update),
        ],
        n,
        repeat,
        min_run_s,
    )
    d_mc, d_dtw = _rates(
        [distance(magnetic_kernels.mmse, windows), distance(magnetic_kernels.dtw, sampled)],
        n,
        repeat,
        min_run_s,
    )
    f_mc, f_dtw, f_np = _rates(
        [filter_step("mass_centered"), filter_step("dtw"), numpy_step()], n, repeat, min_run_s
    )

    state = walk.moved[-1]
    blob = encode_arrays(state_codec.to_arrays(state))
    encode_s, decode_s = (
        1.0 / rate
        for rate in _rates(
            [
                lambda: encode_arrays(state_codec.to_arrays(state)),
                lambda: state_codec.from_arrays(pc.Particles, decode_arrays(blob)),
            ],
            1,
            repeat,
            min_run_s,
        )
    )
    return {
        "particles": n_particles,
        "window": window,
        "repeat": repeat,
        "mass_centered_steps_per_s": mc,
        "dtw_steps_per_s": dtw,
        "speed_ratio": mc / dtw,
        "mmse_per_s": d_mc,
        "dtw_distance_per_s": d_dtw,
        "distance_speed_ratio": d_mc / d_dtw,
        "mass_centered_filter_steps_per_s": f_mc,
        "dtw_filter_steps_per_s": f_dtw,
        "filter_speed_ratio": f_mc / f_dtw,
        "numpy_filter_steps_per_s": f_np,
        "compiled_speedup": f_mc / f_np,
        "dtw_samples_per_step": per_step,
        "state_bytes": len(blob),
        "encode_us": encode_s * 1e6,
        "decode_us": decode_s * 1e6,
    }


def _corridor(seed: int) -> tuple[FloorPlan, MagneticGrid]:
    """The corridor's floor plan and a magnetic map surveyed at every 0.5 m cell centre."""
    length, width = CORRIDOR_M
    plan = plan_from_geojson(
        {
            "type": "FeatureCollection",
            "features": [
                {
                    "type": "Feature",
                    "properties": {"kind": "walkable"},
                    "geometry": {
                        "type": "Polygon",
                        "coordinates": [[[0, 0], [length, 0], [length, width], [0, width], [0, 0]]],
                    },
                }
            ],
        }
    )
    rng = np.random.default_rng([seed, 0])
    # one cell beyond the walls, so the map is known (bilinearly) everywhere inside
    xs, ys = np.meshgrid(np.arange(-0.25, length + 0.5, 0.5), np.arange(-0.25, width + 0.5, 0.5))
    survey = np.column_stack([xs.ravel(), ys.ravel()])
    extent = (-0.5, -0.5, length + 0.5, width + 0.5)
    return plan, grid_from_samples(survey, _field_ut(survey, rng), extent=extent)


def _field_ut(xy: particle.FloatArray, rng: np.random.Generator) -> particle.FloatArray:
    """A corridor-like field: sines along x, a few bumps (cabinets, pillars), some noise."""
    x = xy[:, 0]
    f = 45.0 + 4.0 * np.sin(2 * np.pi * x / 7.3 + 0.4) + 3.0 * np.sin(2 * np.pi * x / 4.1 + 1.3)
    for centre, amplitude in ((12.0, 5.0), (27.0, -4.0), (41.0, 6.0), (52.0, -3.0)):
        f = f + amplitude * np.exp(-((x - centre) ** 2) / (2 * 0.8**2))
    return np.asarray(f + 0.3 * xy[:, 1] + rng.normal(0.0, 0.2, x.shape), dtype=np.float64)


def _record_walk(
    plan: FloorPlan,
    grid: MagneticGrid,
    params: pc.ParticleParams,
    seed: int,
    sample_map: pc.MapSampler,
    valid_move: pc.MoveCheck,
) -> _Walk:
    """Walk the mass-centered filter east along the corridor; keep ``N_INPUTS`` steps
    taken once the windows are full."""
    length, width = CORRIDOR_M
    rng = np.random.default_rng([seed, 1])
    phone = np.random.default_rng([seed, 3])
    truth = np.array([[5.0, width / 2]])
    heading = math.pi / 2  # east, clockwise from north

    def reading() -> float:
        return float(sample(grid, truth)[0] + phone.normal(0.0, 0.5))

    p = particle.initialise(
        (length / 2, width / 2),
        0,
        rng,
        params,
        radius_m=length,
        valid_point=lambda _floor, xy: walkable_at(plan, xy),
    )
    p = particle_weight_update.mass_centered_update(p, reading(), sample_map, params)
    before, moved, observed = [], [], []
    for k in range(params.window + N_INPUTS):
        truth = truth + np.array([[STEP_M, 0.0]])
        q = particle_move.move(p, STEP_M, heading, rng, params, valid_move)
        o = reading()
        if k >= params.window:
            before.append(p)
            moved.append(q)
            observed.append(o)
        p = particle_weight_update.mass_centered_update(q, o, sample_map, params)
        if particle_resampling.effective_sample_size(p) < params.resample_ess_fraction * p.n:
            p = particle_resampling.systematic_resample(p, rng)
    return _Walk(tuple(before), tuple(moved), tuple(observed), heading)


def _rates(
    runs: Sequence[Callable[[], object]], calls: int, repeat: int, min_run_s: float
) -> list[float]:
    """Calls per second of each ``run`` (which makes ``calls`` calls), median of
    ``repeat`` timed runs, the methods alternating within a run, after one warm-up."""
    passes = []
    for run in runs:
        start = time.perf_counter_ns()
        run()
        elapsed_s = max(time.perf_counter_ns() - start, 1) * 1e-9
        passes.append(max(1, math.ceil(min_run_s / elapsed_s)))
    rates: list[list[float]] = [[] for _ in runs]
    for r in range(repeat):
        order = range(len(runs)) if r % 2 == 0 else reversed(range(len(runs)))
        for i in order:
            start = time.perf_counter_ns()
            for _ in range(passes[i]):
                runs[i]()
            elapsed_s = max(time.perf_counter_ns() - start, 1) * 1e-9
            rates[i].append(passes[i] * calls / elapsed_s)
    return [statistics.median(r) for r in rates]
