"""The ``pf_magnetic`` engine on a synthetic corridor with a floor plan, a radio map and a
known magnetic field: it starts from a wrong WiFi fix and the magnetic weights bring it
to the truth; its state survives the array round trip; it re-initialises when WiFi keeps
disagreeing."""

from __future__ import annotations

import numpy as np

from server.positioning.engines import pf_magnetic
from server.positioning.engines.shared.site_maps import FloorRef, SiteMaps
from server.positioning.model import state_codec
from server.positioning.model.events import (
    RadioReading,
    WifiEvent,
    radio_key,
)
from server.positioning.radio.fingerprints import RadioMap
from tests.support.corridor_site import T0, WIDTH_M, rssi, scan, site_maps, walk


def test_a_wrong_wifi_start_converges_on_the_magnetic_field() -> None:
    maps = site_maps()
    params = pf_magnetic.PfMagneticParams()
    rng = np.random.default_rng(7)
    # WiFi places the phone 8 m ahead of where it is
    state, fixes = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params), [scan(T0, 18.0, 1.5)], maps, params, rng
    )
    assert fixes[0].x_m > 14.0
    state, fixes = pf_magnetic.SPEC.run(state, walk(10.0, 30, rng), maps, params, rng)
    steps = [f for f in fixes if f.source == "step"]
    assert len(steps) == 30
    errors = [abs(f.x_m - (10.0 + 0.7 * (i + 1))) for i, f in enumerate(steps)]
    assert np.mean(errors[-5:]) < 1.0, errors
    assert all(0.0 <= f.y_m <= WIDTH_M for f in steps)  # the plan holds the cloud


def test_without_the_field_the_wrong_start_stays_wrong() -> None:
    """The ablation ``weighting="none"``: the same walk, only walls weigh the particles,
    and nothing pulls the cloud back from the 8 m WiFi error."""
    maps = site_maps()
    params = pf_magnetic.PfMagneticParams(weighting="none")
    rng = np.random.default_rng(7)
    state, _ = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params), [scan(T0, 18.0, 1.5)], maps, params, rng
    )
    _, fixes = pf_magnetic.SPEC.run(state, walk(10.0, 30, rng), maps, params, rng)
    steps = [f for f in fixes if f.source == "step"]
    errors = [abs(f.x_m - (10.0 + 0.7 * (i + 1))) for i, f in enumerate(steps)]
    assert np.mean(errors[-5:]) > 3.0, errors


def test_state_round_trip_continues_identically() -> None:
    maps = site_maps()
    params = pf_magnetic.PfMagneticParams()
    events = walk(10.0, 12, np.random.default_rng(1))
    first = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params),
        [scan(T0, 12.0, 1.5)],
        maps,
        params,
        np.random.default_rng(2),
    )[0]
    direct, a = pf_magnetic.SPEC.run(first, events, maps, params, np.random.default_rng(3))
    again = state_codec.from_arrays(pf_magnetic.PfMagneticState, state_codec.to_arrays(first))
    _, b = pf_magnetic.SPEC.run(again, events, maps, params, np.random.default_rng(3))
    assert [(f.x_m, f.y_m, f.cov) for f in a] == [(f.x_m, f.y_m, f.cov) for f in b]
    size = sum(v.nbytes for v in state_codec.to_arrays(direct).values())
    assert size < 120_000  # 3000 particles as float32 plus the step tracker


def test_wifi_that_keeps_disagreeing_restarts_the_cloud() -> None:
    maps = site_maps()
    params = pf_magnetic.PfMagneticParams()
    rng = np.random.default_rng(4)
    state, _ = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params), [scan(T0, 10.0, 1.5)], maps, params, rng
    )
    far = [scan(T0 + 1000 * i, 50.0, 1.5) for i in range(1, 4)]
    state, fixes = pf_magnetic.SPEC.run(state, far, maps, params, rng)
    assert [("reinitialised" in f.diagnostics) for f in fixes] == [False, False, True]
    assert abs(fixes[-1].x_m - 50.0) < 6.0


def test_steps_before_any_fix_are_ignored_and_no_map_still_works() -> None:
    maps = SiteMaps((FloorRef("b", "f0", 0),), site_maps().radio, "v")  # no plan, no field
    params = pf_magnetic.PfMagneticParams()
    rng = np.random.default_rng(5)
    state, fixes = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params), walk(10.0, 3, rng), maps, params, rng
    )
    assert fixes == []
    assert state.cloud is None
    state, fixes = pf_magnetic.SPEC.run(
        state, [scan(T0 + 5000, 20.0, 1.5), *walk(20.0, 5, rng, t0=T0 + 5000)], maps, params, rng
    )
    assert len(fixes) == 6


def test_a_scan_on_another_floor_moves_the_cloud_there_in_place() -> None:
    one = site_maps()
    assert one.radio is not None
    r = one.radio
    n_em = r.mean_dbm.shape[1]
    # floor 1 hears its own access points ("bp*") at the same places
    radio = RadioMap(
        rp_xy=np.vstack([r.rp_xy, r.rp_xy]),
        rp_floor=np.concatenate([r.rp_floor, np.ones_like(r.rp_floor)]),
        mean_dbm=np.block(
            [
                [r.mean_dbm, np.full_like(r.mean_dbm, -100.0)],
                [np.full_like(r.mean_dbm, -100.0), r.mean_dbm],
            ]
        ),
        var_db2=np.ones((2 * len(r.rp_xy), 2 * n_em), dtype=np.float32),
        count=np.block([[r.count, np.zeros_like(r.count)], [np.zeros_like(r.count), r.count]]),
        emitters=r.emitters + tuple(radio_key("wifi", f"bp{i}") for i in range(n_em)),
    )
    maps = SiteMaps(
        (FloorRef("b", "f0", 0), FloorRef("b", "f1", 1)), radio, "v", plans=one.plans * 2
    )
    params = pf_magnetic.PfMagneticParams()
    rng = np.random.default_rng(6)
    state, fixes = pf_magnetic.SPEC.run(
        pf_magnetic.initial_state(params), [scan(T0, 30.0, 1.5)], maps, params, rng
    )
    assert fixes[0].floor == 0
    upstairs = WifiEvent(
        T0 + 1000,
        tuple(RadioReading(f"bp{i}", float(round(v))) for i, v in enumerate(rssi(31.0, 1.5))),
    )
    state, fixes = pf_magnetic.SPEC.run(state, [upstairs], maps, params, rng)
    assert fixes[0].floor == 1
    assert "reinitialised" not in fixes[0].diagnostics
    assert abs(fixes[0].x_m - 30.0) < 3.0
