"""Every registered engine through the same checks: it is declared one way (an
``EngineSpec`` of named handlers, or of a delegate), its state survives the codec
exactly, a seed makes it deterministic, its fixes carry finite values and a floor, and
bad parameters are refused naming the field."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest

from server.positioning.engines.registry import ENGINES, get_engine
from server.positioning.engines.shared.spec import Engine, EngineSpec
from server.positioning.model import state_codec
from server.positioning.model.events import Event, Fix
from server.positioning.model.params import ParamError, as_dict
from server.storage.codec import decode_arrays, encode_arrays
from tests.support.corridor_site import batches, site_maps

MAPS = site_maps()


def replay(
    engine: Engine, seed: int, events: Sequence[Sequence[Event]], through_codec: bool
) -> tuple[object, list[Fix]]:
    params = engine.params()
    state = engine.start(params)
    fixes: list[Fix] = []
    for seq, batch in enumerate(events, start=1):
        if through_codec:  # as the session store keeps it between batches
            state = engine.decode(decode_arrays(encode_arrays(engine.encode(state))))
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(seq,)))
        state, new = engine.step(state, batch, MAPS, params, rng)
        fixes += new
    return state, fixes


@pytest.fixture(scope="module")
def events() -> list[list[Event]]:
    return batches()


@pytest.mark.parametrize("name", sorted(ENGINES))
def test_every_engine_is_declared_as_an_engine_spec(name: str) -> None:
    spec = get_engine(name)
    assert isinstance(spec, EngineSpec)
    assert spec.name == name
    # the handlers a reader finds at the declaration are the engine's own functions
    for route in spec.handlers:
        assert route.handler.__name__ != "<lambda>", route
        assert "<locals>" not in route.handler.__qualname__, route
    assert bool(spec.handlers) != (spec.delegate is not None)
    with pytest.raises(ValueError, match="handlers or a delegate"):
        EngineSpec(
            name="neither",
            params_type=spec.params_type,
            state_type=spec.state_type,
            initial_state=spec.initial_state,
            uses=spec.uses,
            handlers=(),
        )


@pytest.mark.parametrize("name", sorted(ENGINES))
def test_the_state_survives_the_codec_exactly(name: str, events: list[list[Event]]) -> None:
    engine = get_engine(name)
    state, _ = replay(engine, 1, events[:3], through_codec=False)
    arrays = engine.encode(state)
    again = engine.encode(engine.decode(decode_arrays(encode_arrays(arrays))))
    assert again.keys() == arrays.keys()
    for key, value in arrays.items():
        assert again[key].dtype == value.dtype, key
        np.testing.assert_array_equal(again[key], value, err_msg=key)
    # a state with an array missing or of another dtype is refused, not half-read
    key = next(k for k, v in arrays.items() if v.ndim >= 1)
    with pytest.raises(state_codec.StateError, match=key):
        engine.decode({k: v for k, v in arrays.items() if k != key})
    other = np.float32 if arrays[key].dtype != np.float32 else np.float64
    with pytest.raises(state_codec.StateError, match=key):
        engine.decode({**arrays, key: arrays[key].astype(other)})
    # nor one with an array it does not know, or a number where a count belongs
    with pytest.raises(state_codec.StateError, match="unknown arrays: stray"):
        engine.decode({**arrays, "stray": np.zeros(1)})
    count = next(k for k, v in arrays.items() if v.ndim == 0 and v.dtype == np.int64)
    with pytest.raises(state_codec.StateError, match=count):
        engine.decode({**arrays, count: np.array(2.7)})


@pytest.mark.parametrize("name", sorted(ENGINES))
def test_a_seed_makes_it_deterministic_with_or_without_the_codec(
    name: str, events: list[list[Event]]
) -> None:
    engine = get_engine(name)
    _, direct = replay(engine, 7, events, through_codec=False)
    _, stored = replay(engine, 7, events, through_codec=True)
    assert direct, f"{name} gave no fix on a walk with scans"
    assert direct == stored


@pytest.mark.parametrize("name", sorted(ENGINES))
def test_fixes_carry_finite_values_and_a_floor(name: str, events: list[list[Event]]) -> None:
    _, fixes = replay(get_engine(name), 3, events, through_codec=True)
    for fix in fixes:
        assert math.isfinite(fix.x_m), fix
        assert math.isfinite(fix.y_m), fix
        assert 0 <= fix.floor < len(MAPS.floors), fix
        assert all(math.isfinite(c) for c in fix.cov), fix
        assert fix.cov[0] > 0, fix
        assert fix.cov[3] > 0, fix
        assert fix.heading_rad is None or math.isfinite(fix.heading_rad), fix
    # near the walk (the corridor is 60 m long; a fix off it is a broken engine)
    assert all(-5.0 < f.x_m < 65.0 and -5.0 < f.y_m < 8.0 for f in fixes)


@pytest.mark.parametrize("name", sorted(ENGINES))
def test_bad_parameters_are_refused_naming_the_field(name: str) -> None:
    engine = get_engine(name)
    defaults = as_dict(engine.params())
    assert engine.params(defaults) == engine.params()  # the defaults, spelt out, are valid
    with pytest.raises(ParamError) as unknown:
        engine.params({"no_such_parameter": 1})
    assert unknown.value.field == "no_such_parameter"
    with pytest.raises(ParamError) as bad_k:
        engine.params({"k": 0})
    assert bad_k.value.field == "k"
    with pytest.raises(ParamError) as not_a_number:
        engine.params({"min_fix_var_m2": "four"})
    assert not_a_number.value.field == "min_fix_var_m2"
    nested = [k for k, v in defaults.items() if isinstance(v, dict)]
    for key in nested:
        with pytest.raises(ParamError) as deep:
            engine.params({key: {"no_such_parameter": 1}})
        assert deep.value.field == f"{key}.no_such_parameter"
