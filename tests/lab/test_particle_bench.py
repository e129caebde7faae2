"""The particle benchmark runs and reports what it says (no timing is asserted: the
figures are in bench/performance.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lab.particle_bench import particle_bench
from server.positioning.filters.particle_cloud import from_points
from server.positioning.model import state_codec
from server.storage.codec import encode_arrays

RATES = (
    "mass_centered_steps_per_s",
    "dtw_steps_per_s",
    "mmse_per_s",
    "dtw_distance_per_s",
    "mass_centered_filter_steps_per_s",
    "dtw_filter_steps_per_s",
    "numpy_filter_steps_per_s",
)


def encoded_size(n: int, window: int) -> int:
    return len(encode_arrays(state_codec.to_arrays(from_points(np.zeros((n, 2)), 0, window))))


@pytest.mark.parametrize(("n", "window"), [(40, 3), (25, 1)])
def test_reports_every_figure_with_its_type(n: int, window: int) -> None:
    result = particle_bench(n, window=window, repeat=2, min_run_s=0.0)
    assert list(result) == [
        "particles",
        "window",
        "repeat",
        "mass_centered_steps_per_s",
        "dtw_steps_per_s",
        "speed_ratio",
        "mmse_per_s",
        "dtw_distance_per_s",
        "distance_speed_ratio",
        "mass_centered_filter_steps_per_s",
        "dtw_filter_steps_per_s",
        "filter_speed_ratio",
        "numpy_filter_steps_per_s",
        "compiled_speedup",
        "dtw_samples_per_step",
        "state_bytes",
        "encode_us",
        "decode_us",
    ]
    assert (result["particles"], result["window"], result["repeat"]) == (n, window, 2)
    for name in ("particles", "window", "repeat", "dtw_samples_per_step", "state_bytes"):
        assert type(result[name]) is int, name
    ratios = ("speed_ratio", "distance_speed_ratio", "filter_speed_ratio", "compiled_speedup")
    for name in (*RATES, *ratios):
        value = result[name]
        assert isinstance(value, float), name
        assert math.isfinite(value), name
        assert value > 0, name
    for name in ("encode_us", "decode_us"):
        assert isinstance(result[name], float), name
        assert result[name] > 0, name
    assert result["speed_ratio"] == pytest.approx(
        result["mass_centered_steps_per_s"] / result["dtw_steps_per_s"]
    )
    assert result["state_bytes"] == encoded_size(n, window)


def test_the_state_at_3000_particles_fits_in_100_kb() -> None:
    # the arrays hold 90,024 bytes (state_codec.to_arrays); the codec adds names and shapes
    assert encoded_size(3000, 3) == 90_160 <= 100_000


def test_refuses_no_runs() -> None:
    with pytest.raises(ValueError, match="repeat"):
        particle_bench(10, repeat=0)
