"""Engine parameters given as text."""

from __future__ import annotations

import pytest

from server.lab.engine_params import engine_params


def test_engine_params_replace_scalars_by_name() -> None:
    params = engine_params("two_stage_ekf", {"k": "8", "partition_radius_m": "5"})
    assert (params.k, params.partition_radius_m) == (8, 5.0)
    assert engine_params("wknn").k == 4
    with pytest.raises(ValueError, match="no parameter 'nope'"):
        engine_params("wknn", {"nope": "1"})
    with pytest.raises(ValueError, match="'k': 'x' is not a int"):
        engine_params("wknn", {"k": "x"})
    assert engine_params("pf_magnetic", {"weighting": "dtw"}).weighting == "dtw"
    with pytest.raises(ValueError, match="'tracker' of two_stage_ekf is not a number"):
        engine_params("two_stage_ekf", {"tracker": "x"})
    with pytest.raises(ValueError, match="k must be at least 1"):
        engine_params("wknn", {"k": "0"})
