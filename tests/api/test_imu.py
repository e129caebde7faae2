"""Raw IMU events on the wire: validation naming the field, the core round trip, the batch
limit, recorded traces through the API, and raw samples in, fixes out (HTTP and socket)."""

from __future__ import annotations

import asyncio
import json
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

import httpx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from websockets.asyncio.client import connect

from client_sim.imu import Gait, blocks, synthesize_walk
from lab.replay import batches
from server.api import convert
from server.api.schemas.events import ImuIn
from server.api.schemas.sessions import MAX_IMU_ROWS_PER_BATCH, LiveBatch
from server.positioning.model.events import ImuEvent
from server.storage.ilc_trace_format import read_trace
from tests.support.admin_key import ADMIN_KEY
from tests.support.datasets import dataset_dir
from tests.support.toy_site import WIDTH_M, ToySite, build_toy_site, rssi_at

T0 = 1_700_000_000_000
G_MS2 = 9.80665
Event = dict[str, Any]


@pytest.fixture
async def site(client: httpx.AsyncClient, admin: dict[str, str]) -> ToySite:
    return await build_toy_site(client, admin)


async def open_session(
    client: httpx.AsyncClient, site: ToySite, engine: str = "step_ekf"
) -> tuple[str, dict[str, str]]:
    r = await client.post(
        "/v1/sessions", json={"site_id": site.site_id, "engine": engine}, headers=site.device
    )
    assert r.status_code == 201, r.text
    body = r.json()
    return body["id"], {"Authorization": f"Bearer {body['token']}"}


def scan(t: int, x: float, y: float) -> Event:
    return {"type": "wifi", "t": t, "readings": rssi_at(x, y, 0)}


def imu(t: int = T0, n: int = 50, period_ms: int = 20) -> Event:
    """A valid block of ``n`` samples of every sensor, phone lying flat and still."""
    times = [t + i * period_ms for i in range(n)]
    return {
        "type": "imu",
        "t": t,
        "accel": [[ti, 0.01, -0.02, G_MS2] for ti in times],
        "gyro": [[ti, 0.001, 0.0, -0.002] for ti in times],
        "magnetic": [[ti, 0.0, 20.0, -40.0] for ti in times],
        "magnetic_calibrated": False,
        "rotation": [[ti, 0.0, 0.0, 0.0, 1.0] for ti in times],
        "pressure": [[ti, 1013.25] for ti in times[::5]],
    }


def changed(**fields: Any) -> Callable[[Event], Event]:
    return lambda e: {**e, **fields}


def row_set(sensor: str, row: int, column: int, value: Any) -> Callable[[Event], Event]:
    def change(e: Event) -> Event:
        rows = [list(r) for r in e[sensor]]
        rows[row][column] = value
        return {**e, sensor: rows}

    return change


def times_at(sensor: str, times: list[int]) -> Callable[[Event], Event]:
    def change(e: Event) -> Event:
        rows = [[t, *e[sensor][0][1:]] for t in times]
        return {**e, sensor: rows}

    return change


EMPTY: dict[str, list[Any]] = {
    "accel": [],
    "gyro": [],
    "magnetic": [],
    "rotation": [],
    "pressure": [],
}


def case(name: str, change: Callable[[Event], Event], field: str) -> Any:
    return pytest.param(change, field, id=name)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        # finite values, integer times within the timestamp range
        case("nan", row_set("accel", 3, 2, float("nan")), "events.0.accel.3.2"),
        case("infinity", row_set("gyro", 0, 1, float("inf")), "events.0.gyro.0.1"),
        case("fractional time", row_set("accel", 1, 0, T0 + 20.5), "events.0.accel.1.0"),
        case("negative time", row_set("magnetic", 0, 0, -1), "events.0.magnetic.0.0"),
        case("text time", row_set("pressure", 0, 0, "soon"), "events.0.pressure.0.0"),
        case("huge t", changed(t=2**60), "events.0.t"),
        case("t of 1970", changed(t=0), "events.0.t"),
        case("t of the year 287000", changed(t=2**53), "events.0.t"),
        case(
            "sample of 2100", row_set("pressure", 0, 0, 4_102_444_800_000), "events.0.pressure.0.0"
        ),
        # samples within [t, t + 60 s], strictly increasing per sensor
        case("before t", row_set("accel", 0, 0, T0 - 1), "events.0.accel"),
        case("after t + 60 s", times_at("gyro", [T0, T0 + 60_001]), "events.0.gyro"),
        case("repeated time", times_at("magnetic", [T0, T0 + 40, T0 + 40]), "events.0.magnetic"),
        case("backwards", times_at("rotation", [T0 + 40, T0 + 20]), "events.0.rotation"),
        # plausible ranges
        case("accel", row_set("accel", 0, 1, 160.5), "events.0.accel.0.1"),
        case("gyro", row_set("gyro", 0, 3, -35.5), "events.0.gyro.0.3"),
        case("magnetic", row_set("magnetic", 0, 2, 5001.0), "events.0.magnetic.0.2"),
        case("magnetic 1e308", row_set("magnetic", 1, 1, -1e308), "events.0.magnetic.1.1"),
        case("quaternion", row_set("rotation", 0, 4, 1.01), "events.0.rotation.0.4"),
        case("not unit", row_set("rotation", 0, 4, 0.5), "events.0.rotation"),
        case("low pressure", row_set("pressure", 0, 1, 299.0), "events.0.pressure.0.1"),
        case("high pressure", row_set("pressure", 0, 1, 1100.5), "events.0.pressure.0.1"),
        # plausible rates: 1 kHz is refused
        case("1 kHz", times_at("accel", [T0 + i for i in range(10)]), "events.0.accel"),
        # row shapes, sizes, the flag, unknown fields, nothing at all
        case("null value", row_set("accel", 0, 3, None), "events.0.accel.0.3"),
        case("no w", changed(rotation=[[T0, 0.0, 0.0, 1.0]]), "events.0.rotation.0.4"),
        case(
            "12001 rows",
            changed(accel=[[T0 + 2 * i, 0, 0, G_MS2] for i in range(12_001)]),
            "events.0.accel",
        ),
        case("flag", changed(magnetic_calibrated="maybe"), "events.0.magnetic_calibrated"),
        case("unknown sensor", changed(temperature=[]), "events.0.temperature"),
        case("no samples", changed(**EMPTY), "events.0"),
    ],
)
async def test_malformed_imu_events_get_422_naming_the_field(
    client: httpx.AsyncClient, site: ToySite, change: Callable[[Event], Event], field: str
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    r = await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5), imu(T0)]}, headers=auth)
    assert r.status_code == 200, r.text
    before = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    body = json.dumps({"seq": 2, "events": [change(imu(T0 + 1000))]})  # NaN as a bare token
    r = await client.post(url, content=body, headers={**auth, "content-type": "application/json"})
    assert r.status_code == 422, r.text
    message = r.json()["message"]
    assert message.startswith(f"{field}:") or f"; {field}:" in message, message
    after = (await client.get(f"/v1/sessions/{sid}", headers=auth)).json()
    assert after == before


async def test_valid_imu_events_are_accepted_and_ignored_by_step_ekf(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    r = await client.post(url, json={"seq": 1, "events": [scan(T0, 5, 5), imu(T0)]}, headers=auth)
    assert r.status_code == 200, r.text
    assert [f["source"] for f in r.json()["fixes"]] == ["wifi"]
    edge_cases = [
        imu(T0 + 1000, n=11, period_ms=2),  # exactly 500 Hz
        imu(T0 + 2000, n=2, period_ms=60_000),  # t and t + 60 s
        {"type": "imu", "t": T0 + 3000, "pressure": [[T0 + 3000, 1013]]},  # one sensor only
    ]
    r = await client.post(url, json={"seq": 2, "events": edge_cases}, headers=auth)
    assert r.status_code == 200, r.text
    assert r.json()["fixes"] == []


def random_imu_event(rng: np.random.Generator, t_ms: int) -> ImuEvent:
    def rows(n: int, scale: float, width: int) -> np.ndarray:
        times = t_ms + np.cumsum(rng.integers(2, 40, n))
        return np.column_stack([times, rng.uniform(-scale, scale, (n, width - 1))])

    quaternions = rng.normal(size=(30, 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    rotation = np.column_stack([t_ms + np.arange(30) * 7, quaternions])
    pressure = np.column_stack([t_ms + np.arange(5) * 100, rng.uniform(900, 1050, 5)])
    return ImuEvent(
        t_ms,
        accel=rows(40, 150.0, 4),
        gyro=rows(25, 30.0, 4),
        magnetic=rows(0, 1.0, 4),
        magnetic_calibrated=False,
        rotation=rotation,
        pressure=pressure,
    )


def test_imu_round_trip_is_exact() -> None:
    rng = np.random.default_rng(7)
    event = random_imu_event(rng, T0)
    wire = json.loads(json.dumps(convert.to_wire(event)))  # through JSON text, as sent
    assert wire["type"] == "imu"
    assert wire["t"] == T0
    assert wire["magnetic"] == []
    assert all(isinstance(row[0], int) for row in wire["accel"])
    back = convert.to_event(ImuIn.model_validate(wire))
    assert isinstance(back, ImuEvent)
    assert back.t_ms == event.t_ms
    assert back.magnetic_calibrated is False
    for name, samples in event.sensors().items():
        got = back.sensors()[name]
        assert got.dtype == np.float64
        assert got.shape == samples.shape, name
        np.testing.assert_array_equal(got, samples)
    assert convert.to_wire(back) == wire


@settings(max_examples=50, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(2, 1000),  # ms since the sample before: at most 500 Hz
            *[st.floats(-160, 160, allow_nan=False, allow_infinity=False)] * 3,
        ),
        min_size=1,
        max_size=30,
    ),
    st.booleans(),
)
def test_any_valid_accel_block_round_trips(
    rows: list[tuple[int, float, float, float]], calibrated: bool
) -> None:
    times = np.cumsum([gap for gap, *_ in rows]).tolist()
    accel = [[T0 + t, x, y, z] for t, (_, x, y, z) in zip(times, rows, strict=True)]
    wire = {"type": "imu", "t": T0, "accel": accel, "magnetic_calibrated": calibrated}
    event = convert.to_event(ImuIn.model_validate(wire))
    assert convert.to_wire(event) == {**{name: [] for name in EMPTY}, **wire}


def accel_only(t: int, n: int, period_ms: int = 5) -> Event:
    return {"type": "imu", "t": t, "accel": [[t + i * period_ms, 0, 0, G_MS2] for i in range(n)]}


async def test_a_batch_holds_at_most_60000_imu_rows(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    # five minutes at 200 Hz, one minute per event, is the most one batch can carry
    full = [accel_only(T0 + 60_000 * i, 12_000) for i in range(5)]
    assert sum(len(e["accel"]) for e in full) == MAX_IMU_ROWS_PER_BATCH
    over = [*full, accel_only(T0 + 300_000, 1)]
    r = await client.post(url, json={"seq": 1, "events": over}, headers=auth)
    assert r.status_code == 422, r.text
    assert r.json()["message"].startswith("events: "), r.json()["message"]
    assert "60001" in r.json()["message"]
    r = await client.post(url, json={"seq": 1, "events": full}, headers=auth)
    assert r.status_code == 200, r.text


def test_the_batch_limit_holds_on_the_socket_too() -> None:
    over = [accel_only(T0 + 60_000 * i, 12_000) for i in range(5)]
    over.append(accel_only(T0 + 300_000, 1))
    with pytest.raises(ValueError, match="at most 60000"):
        LiveBatch.model_validate({"type": "batch", "seq": 1, "events": over})


async def test_reused_seq_with_other_imu_samples_is_a_conflict(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    minute = imu(T0, n=3000)
    other = {**minute, "accel": [list(r) for r in minute["accel"]]}
    other["accel"][1500][3] = 12.0
    assert (await client.post(url, json={"seq": 1, "events": [minute]}, headers=auth)).is_success
    r = await client.post(url, json={"seq": 1, "events": [other]}, headers=auth)
    assert r.status_code == 409, r.text


async def test_recorded_trace_posts_as_imu_batches(
    client: httpx.AsyncClient, site: ToySite
) -> None:
    """The blocks the evaluation replays of a real ILC trace pass the wire validation."""
    path = dataset_dir("ilc20-sample") / "sample_raw" / "5dd5206850e04e0006f56460.txt"
    trace = read_trace(path)
    events = trace.events(imu=True)
    assert any(isinstance(e, ImuEvent) for e in events)
    sid, auth = await open_session(client, site)
    url = f"/v1/sessions/{sid}/batches"
    for seq, batch in enumerate(batches(events), start=1):
        body = {"seq": seq, "events": [convert.to_wire(e) for e in batch]}
        r = await client.post(url, json=body, headers=auth)
        assert r.status_code == 200, r.text


# ---------------------------------------------------------------- raw samples in, fixes out

WALK_Y_M = 4.0
STEP_M = 0.7
STEP_HZ = 2.0
TURN_S = (10.0, 11.0)  # standing, turning from east to west
TURN_HEADINGS_RAD = (math.pi / 2, 3 * math.pi / 2)  # clockwise, through south
WALK_S = 20.0


def heading_rad(t_s: float) -> float:
    """Clockwise from north: east, a half turn, then west."""
    return float(np.interp(t_s, TURN_S, TURN_HEADINGS_RAD))


def true_x_m(t_s: float) -> float:
    east = min(t_s, TURN_S[0]) * STEP_M * STEP_HZ
    west = max(t_s - TURN_S[1], 0.0) * STEP_M * STEP_HZ
    return 3.0 + east - west


def walk_batches() -> list[list[Event]]:
    """One batch per second: a block of raw samples (``client_sim.imu``, 50 Hz) of a phone
    held flat, pointing where it walks, and a WiFi scan every two seconds."""
    trace = synthesize_walk(
        lambda t_s: np.interp(t_s, TURN_S, TURN_HEADINGS_RAD),
        WALK_S,
        np.random.default_rng(11),
        walking=[(0.0, TURN_S[0]), (TURN_S[1], WALK_S)],
        gait=Gait(cadence_hz=STEP_HZ, step_length_m=STEP_M, bounce_ms2=2.0),
        t0_ms=T0,
    )
    out = []
    for second, block in enumerate(blocks(trace)):
        batch = [block.event()]
        if second % 2 == 0:
            batch.insert(0, scan(T0 + 1000 * second, true_x_m(second), WALK_Y_M))
        out.append(batch)
    assert len(out) == WALK_S
    return out


def check_walk_fixes(fixes: list[dict[str, Any]]) -> None:
    """Steps found in the raw samples, pointing the right way; every scan used; and with
    a scan every 2 s that alone places the phone within a metre here, the track ends near
    the truth."""
    sources = Counter(f["source"] for f in fixes)
    n_steps = round((WALK_S - (TURN_S[1] - TURN_S[0])) * STEP_HZ)
    assert sources["wifi"] >= 8, sources  # of 10 scans
    assert 0.75 * n_steps <= sources["step"] <= 1.25 * n_steps, sources
    assert {f["engine"] for f in fixes} == {"two_stage_ekf"}
    for fix in fixes:
        assert -3.0 <= fix["x_m"] <= WIDTH_M + 3.0, fix
        assert math.isfinite(fix["uncertainty_m"]), fix
        t_s = (fix["t"] - T0) / 1000
        if fix["source"] == "step" and fix["heading_rad"] is not None:
            off = fix["heading_rad"] - heading_rad(t_s)
            assert abs((off + math.pi) % (2 * math.pi) - math.pi) < 0.5, fix
    last = fixes[-1]
    error_m = math.hypot(last["x_m"] - true_x_m((last["t"] - T0) / 1000), last["y_m"] - WALK_Y_M)
    assert error_m < 3.0, last


async def test_raw_imu_in_fixes_out_over_http(client: httpx.AsyncClient, site: ToySite) -> None:
    sid, auth = await open_session(client, site, engine="two_stage_ekf")
    fixes: list[dict[str, Any]] = []
    for seq, events in enumerate(walk_batches(), start=1):
        r = await client.post(
            f"/v1/sessions/{sid}/batches", json={"seq": seq, "events": events}, headers=auth
        )
        assert r.status_code == 200, r.text
        fixes += r.json()["fixes"]
    check_walk_fixes(fixes)


async def test_raw_imu_in_fixes_out_over_the_websocket(live_url: str) -> None:
    admin = {"Authorization": f"Bearer {ADMIN_KEY}"}
    async with httpx.AsyncClient(base_url=live_url) as client:
        site = await build_toy_site(client, admin)
        sid, auth = await open_session(client, site, engine="two_stage_ekf")
        token = auth["Authorization"].removeprefix("Bearer ")
        ws_url = live_url.replace("http", "ws", 1) + f"/v1/sessions/{sid}/live"
        async with connect(ws_url, additional_headers={"Authorization": f"Bearer {token}"}) as ws:

            async def receive() -> dict[str, Any]:
                message: dict[str, Any] = json.loads(await asyncio.wait_for(ws.recv(), 10))
                assert message["type"] != "error", message
                return message

            assert (await receive())["type"] == "ready"
            results: list[dict[str, Any]] = []
            pushed: list[dict[str, Any]] = []
            for seq, events in enumerate(walk_batches(), start=1):
                await ws.send(json.dumps({"type": "batch", "seq": seq, "events": events}))
                while len(results) < seq:
                    message = await receive()
                    (results if message["type"] == "batch_result" else pushed).append(message)
            fixes = [f for result in results for f in result["fixes"]]
            while len(pushed) < len(fixes):
                pushed.append(await receive())
    assert [r["seq"] for r in results] == list(range(1, len(results) + 1))
    assert [m["fix"] for m in pushed] == fixes
    check_walk_fixes(fixes)


@pytest.mark.parametrize("engine", ["two_stage_ekf", "everywhere_ekf"])
async def test_samples_without_gravity_do_not_break_a_session(
    client: httpx.AsyncClient, site: ToySite, engine: str
) -> None:
    sid, auth = await open_session(client, site, engine=engine)
    odd = {
        "type": "imu",
        "t": T0,
        "accel": [[T0, 0.0, 0.0, 0.0]],
        "gyro": [[T0, 0.0, 0.0, 0.1], [T0 + 20, 0.0, 0.0, 0.1]],
    }
    url = f"/v1/sessions/{sid}/batches"
    r = await client.post(url, json={"seq": 1, "events": [odd]}, headers=auth)
    assert r.status_code == 200, r.text
    r = await client.post(url, json={"seq": 2, "events": [imu(T0 + 1000)]}, headers=auth)
    assert r.status_code == 200, r.text
