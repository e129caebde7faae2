"""Map quality of a floor: coverage against the floor plan, cell sampling, freshness and
emitters, on a toy floor whose expected figures follow from its geometry."""

from __future__ import annotations

import math
from datetime import UTC, datetime, timedelta

import httpx
import pytest

from tests.support.quality_floor import GHOST, SHADOWING_DB, magnetic_line, new_site
from tests.support.toy_site import AP_XY, rssi_at


async def test_quality_of_a_surveyed_floor(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    r = await client.get(f"/v1/floors/{floor}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    q = r.json()
    assert q["floor_id"] == floor
    assert q["radio_map"]["version"] == 2
    assert q["magnetic_map"]["version"] == 1

    # radio: the 100 surveyed cells less the 4 under the pillar, plus the upload's cell
    cov = q["coverage"]
    assert cov["walkable_area_known"] is True
    assert cov["radio"] == pytest.approx((100 - 4 + 1) / 196)
    # magnetic: the line's 40 half-metre cells of the 784 walkable ones
    assert cov["magnetic"] == pytest.approx(40 / 784)

    # every surveyed RP: 2 points x 16 APs (both levels' 8 are heard); one RP of 1 reading
    radio = q["radio_cells"]
    assert radio["n_reference_points"] == 101
    assert radio["readings_per_rp"] == {"p10": 32.0, "p50": 32.0, "p90": 32.0}
    assert radio["emitters_per_rp"]["p50"] == 16.0
    assert 1.0 <= radio["var_db2"]["p50"] <= radio["var_db2"]["p90"]

    mag = q["magnetic_cells"]
    assert mag["known_cells"] == 40
    assert mag["samples_per_cell"] == {"p10": 2.0, "p50": 2.0, "p90": 2.0}
    assert 0.0 <= mag["var_ut2"]["p50"] <= mag["var_ut2"]["p90"]

    fresh = q["freshness"]
    assert fresh["n_points"] == 201
    assert fresh["n_surveyed_points"] == 200
    assert fresh["n_uploads"] == 1
    assert fresh["n_cells"] == 101
    newest = datetime.fromisoformat(fresh["newest"])
    oldest = datetime.fromisoformat(fresh["oldest"])
    assert datetime.now(UTC) - newest < timedelta(minutes=5)
    assert timedelta(days=59) < newest - oldest < timedelta(days=61)
    assert fresh["cell_age_days"]["p90"] < 1.0  # 100 of the 101 cells are new

    em = q["emitters"]
    assert em["seen"] == 17
    # level 0's APs within 4 m (-55 dBm) of the surveyed half: (0,0) (10,0) (0,10) (10,10)
    # (5,5); level 1's are 20 dB weaker, never strong
    assert em["fixed"] == 5
    assert em["retired"] == 1  # the ghost
    by_key = {p["key"]: p for p in em["positions"]}
    assert GHOST not in by_key  # one reading: no fit
    assert em["unlocated"] == 17 - len(em["positions"])
    # level 0's AP at (5, 5), in the middle of the survey: found to within a metre and
    # about its stated uncertainty; the path loss recovered, the residual the shadowing
    centre = by_key["02:00:00:00:00:06"]
    assert centre["kind"] == "wifi"
    assert centre["n"] == 200
    error_m = math.dist((centre["x_m"], centre["y_m"]), AP_XY[6])
    assert error_m < 1.0
    assert 0.0 < max(centre["xy_std_m"]) < 1.0
    assert error_m < 4.0 * math.hypot(*centre["xy_std_m"])
    assert centre["p0_dbm"] == pytest.approx(-40.0, abs=1.5)
    assert centre["exponent"] == pytest.approx(2.5, abs=0.2)
    assert centre["residual_rms_db"] == pytest.approx(SHADOWING_DB, rel=0.2)
    # level 1's AP at (5, 5), heard 20 dB weaker from level 0
    below = by_key["02:00:00:00:01:06"]
    assert math.dist((below["x_m"], below["y_m"]), AP_XY[6]) < 2.0
    assert below["p0_dbm"] == pytest.approx(-60.0, abs=2.0)


async def test_query_parameters(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    floor, _ = surveyed
    url = f"/v1/floors/{floor}/maps/quality"
    r = await client.get(url, params={"max_emitters": 2, "retired_after_days": 90}, headers=admin)
    assert r.status_code == 200, r.text
    em = r.json()["emitters"]
    assert em["retired"] == 0  # the ghost was heard 60 days ago: inside 90
    # every AP has 200 readings: ties go by key
    assert [p["key"] for p in em["positions"]] == ["02:00:00:00:00:00", "02:00:00:00:00:01"]
    assert all(
        math.dist((p["x_m"], p["y_m"]), xy) < 2.0
        for p, xy in zip(em["positions"], AP_XY[:2], strict=True)
    )

    r = await client.get(url, params={"max_emitters": 0}, headers=admin)
    assert r.status_code == 200, r.text
    assert r.json()["emitters"]["positions"] == []
    assert r.json()["emitters"]["unlocated"] == 0

    for bad in ({"max_emitters": 501}, {"retired_after_days": 0}):
        r = await client.get(url, params=bad, headers=admin)
        assert r.status_code == 422, r.text
        assert next(iter(bad)) in r.json()["message"]


async def test_floor_without_its_own_maps(
    client: httpx.AsyncClient, admin: dict[str, str], surveyed: tuple[str, str]
) -> None:
    """Level 1 shares the building's radio map but has no RP, plan, grid or point."""
    _, upper = surveyed
    r = await client.get(f"/v1/floors/{upper}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    q = r.json()
    assert q["radio_map"] is not None
    assert q["magnetic_map"] is None
    assert q["coverage"] == {"radio": 0.0, "magnetic": 0.0, "walkable_area_known": False}
    assert q["radio_cells"]["n_reference_points"] == 0
    assert q["emitters"]["seen"] == 0


async def test_floor_without_a_plan(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    """Without a plan the shares are over the maps' own extent."""
    _, building_id, floors = await new_site(client, admin)
    # three of the four 1 m cells of the box [0, 2) x [0, 2)
    points = [
        {"x_m": x, "y_m": y, "floor": 0, "wifi": rssi_at(x, y, 0)}
        for x, y in ((0.5, 0.5), (1.5, 0.5), (0.5, 1.5))
    ]
    r = await client.post(
        f"/v1/buildings/{building_id}/survey", json={"points": points}, headers=admin
    )
    assert r.status_code == 201, r.text
    # the line's 40 cells in a grid of 42 x 3 (one empty cell around the samples' box)
    r = await client.post(
        f"/v1/floors/{floors[0]}/magnetic-survey",
        json={"lines": [magnetic_line(5.25)]},
        headers=admin,
    )
    assert r.status_code == 201, r.text
    r = await client.get(f"/v1/floors/{floors[0]}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    cov = r.json()["coverage"]
    assert cov["walkable_area_known"] is False
    assert cov["radio"] == pytest.approx(3 / 4)
    assert cov["magnetic"] == pytest.approx(40 / (42 * 3))


async def test_floor_without_any_map(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    _, _, floors = await new_site(client, admin)
    r = await client.get(f"/v1/floors/{floors[0]}/maps/quality", headers=admin)
    assert r.status_code == 200, r.text
    assert r.json() == {
        "floor_id": floors[0],
        "radio_map": None,
        "magnetic_map": None,
        "coverage": {"radio": 0.0, "magnetic": 0.0, "walkable_area_known": False},
        "radio_cells": {
            "n_reference_points": 0,
            "readings_per_rp": None,
            "emitters_per_rp": None,
            "var_db2": None,
        },
        "magnetic_cells": {"known_cells": 0, "samples_per_cell": None, "var_ut2": None},
        "freshness": {
            "newest": None,
            "oldest": None,
            "n_cells": 0,
            "cell_age_days": None,
            "n_points": 0,
            "n_surveyed_points": 0,
            "n_uploads": 0,
        },
        "emitters": {"seen": 0, "fixed": 0, "retired": 0, "positions": [], "unlocated": 0},
    }


async def test_unknown_floor_and_no_admin(client: httpx.AsyncClient, admin: dict[str, str]) -> None:
    missing = "0" * 32
    r = await client.get(f"/v1/floors/{missing}/maps/quality", headers=admin)
    assert r.status_code == 404, r.text
    assert r.json()["detail"][0]["loc"] == ["floor_id"]
    assert missing in r.json()["message"]

    r = await client.get(f"/v1/floors/{missing}/maps/quality")
    assert r.status_code == 401
    r = await client.get(
        f"/v1/floors/{missing}/maps/quality", headers={"Authorization": "Bearer nope"}
    )
    assert r.status_code == 401
