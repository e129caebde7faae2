"""Engine parameters given as text."""

from __future__ import annotations

import pytest

from lab.engine_params import engine_params
from server.positioning.engines.pf_magnetic import PfMagneticParams
from server.positioning.engines.two_stage_ekf import TwoStageParams
from server.positioning.engines.wknn import WknnParams


def test_engine_params_replace_parameters_by_dotted_name() -> None:
    params = engine_params("two_stage_ekf", {"k": "8", "partition_radius_m": "5"})
    assert isinstance(params, TwoStageParams)
    assert (params.k, params.partition_radius_m) == (8, 5.0)
    assert isinstance(params.partition_radius_m, float)
    assert engine_params("wknn") == WknnParams()
    with pytest.raises(ValueError, match="nope: unknown parameter"):
        engine_params("wknn", {"nope": "1"})
    with pytest.raises(ValueError, match="k: must be an integer"):
        engine_params("wknn", {"k": "x"})
    pf = engine_params("pf_magnetic", {"weighting": "dtw", "particles.n": "500"})
    assert isinstance(pf, PfMagneticParams)
    assert (pf.weighting, pf.particles.n) == ("dtw", 500)
    with pytest.raises(ValueError, match="tracker: must be an object of parameters"):
        engine_params("two_stage_ekf", {"tracker": "x"})
    with pytest.raises(ValueError, match="k: must be at least 1"):
        engine_params("wknn", {"k": "0"})
    with pytest.raises(ValueError, match=r"particles\.n: must be at most 20000"):
        engine_params("pf_magnetic", {"particles.n": "20001"})
