"""Kill -9 the worker in the middle of a batch of uploads and start it again: every upload
ends settled with a reason, none is lost, none is folded twice.

Run in the shape the suite is configured for: with PostgreSQL + Redis a separate
``indoorpos worker`` process is killed; embedded, the ``indoorpos serve`` process that
runs the in-process worker (and its in-process queue) is killed.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.config import Settings
from tests.support.admin_key import ADMIN_KEY
from tests.support.datasets import DATA_DIR

TRACES = DATA_DIR / "ilc20-sample" / "site2" / "F4" / "path_data_files"
VISIBILITY_S = 2.0  # short, so a killed worker's entry comes back quickly
SETTLE_TIMEOUT_S = 180.0
N_UPLOADS = 10
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not TRACES.is_dir(), reason="../shared/data is not beside us"),
]


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _env(settings: Settings, data_dir: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    env |= {
        "INDOORPOS_ADMIN_KEY": ADMIN_KEY,
        "INDOORPOS_DATA_DIR": str(data_dir),
        "INDOORPOS_UPLOAD_VISIBILITY_S": str(VISIBILITY_S),
    }
    if settings.database_url:
        env["INDOORPOS_DATABASE_URL"] = settings.database_url
    if settings.redis_url:
        env["INDOORPOS_REDIS_URL"] = settings.redis_url
    return env


class Process:
    """A CLI process of ours, killed with SIGKILL (no clean-up of any kind)."""

    def __init__(self, args: list[str], env: dict[str, str], log: Path) -> None:
        self.log = log.open("ab")
        self.proc = subprocess.Popen(
            [str(Path(sys.executable).parent / "indoorpos"), *args],
            env=env,
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )

    def kill9(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(timeout=10)
        assert self.proc.returncode == -signal.SIGKILL

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.kill9()
        self.log.close()


@pytest.fixture
def processes() -> Iterator[list[Process]]:
    started: list[Process] = []
    yield started
    for p in started:
        p.stop()


def _wait_ready(url: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/readyz", timeout=2).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.1)
    pytest.fail(f"{url} did not become ready")


def _statuses(http: httpx.Client, ids: list[str]) -> list[dict[str, Any]]:
    return [http.get(f"/v1/uploads/{i}").raise_for_status().json() for i in ids]


def test_killed_worker_loses_and_repeats_nothing(
    settings: Settings, tmp_path: Path, processes: list[Process]
) -> None:
    production = settings.redis_url is not None
    env = _env(settings, tmp_path / "data")
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    serve_args = ["serve", "--port", str(port)]
    # the uploads go in first, with no worker running anywhere
    quiet = Process(serve_args, env | {"INDOORPOS_IN_PROCESS_WORKER": "false"}, tmp_path / "a.log")
    processes.append(quiet)
    _wait_ready(url)

    admin = {"Authorization": f"Bearer {ADMIN_KEY}"}
    with httpx.Client(base_url=url, headers=admin, timeout=30) as http:
        site = http.post("/v1/sites", json={"name": "crash"}).raise_for_status().json()
        building = (
            http.post(f"/v1/sites/{site['id']}/buildings", json={"name": "b"})
            .raise_for_status()
            .json()
        )
        floor = (
            http.post(f"/v1/buildings/{building['id']}/floors", json={"level": 3})
            .raise_for_status()
            .json()
        )
        ids = []
        for path in sorted(TRACES.glob("*.txt.xz"))[:N_UPLOADS]:
            r = http.post(
                "/v1/uploads",
                params={"site_id": site["id"]},
                content=path.read_bytes(),
                headers={"content-type": "application/x-xz", "idempotency-key": path.name},
            )
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        assert len(ids) == N_UPLOADS

        # then a worker: a separate process, or embedded the api process running its own
        if production:
            processes.append(Process(["worker"], env, tmp_path / "worker.log"))
        else:
            quiet.stop()
            processes.append(Process(serve_args, env, tmp_path / "serve.log"))
            _wait_ready(url)

        # kill the worker once it has settled something and has more to do
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        while time.monotonic() < deadline:
            states = [u["status"] for u in _statuses(http, ids)]
            if "done" in states and ("queued" in states or "processing" in states):
                break
            assert "queued" in states or "processing" in states, f"all settled: {states}"
            time.sleep(0.02)
        else:
            pytest.fail(f"no upload settled in time: {states}")
        victim = processes[-1]
        victim.kill9()
        killed_with = [u["status"] for u in _statuses(http, ids)] if production else None

        # start it again
        processes.append(
            Process(
                ["worker"] if production else serve_args,
                env,
                tmp_path / ("worker.log" if production else "serve.log"),
            )
        )
        if not production:
            _wait_ready(url)
        while time.monotonic() < deadline:
            uploads = _statuses(http, ids)
            if all(u["status"] not in ("queued", "processing") for u in uploads):
                break
            time.sleep(0.2)
        else:
            pytest.fail(f"uploads did not settle: {[u['status'] for u in uploads]}")

    assert killed_with is None or "done" in killed_with
    for u in uploads:
        assert u["status"] in ("done", "rejected"), u
        assert u["report"], u
        if u["status"] == "rejected":
            assert u["report"]["reason"], u
    done = [u for u in uploads if u["status"] == "done"]
    assert done
    # folded once: the building's newest radio map holds exactly the scans of the uploads
    # that are done, its newest magnetic map their samples, one version per upload
    with httpx.Client(base_url=url, headers=admin, timeout=30) as http:
        radio = http.get(f"/v1/buildings/{building['id']}/radio-maps").raise_for_status().json()
        magnetic = http.get(f"/v1/floors/{floor['id']}/magnetic-maps").raise_for_status().json()
    assert radio["count"] == len(done)
    assert radio["items"][-1]["n_survey_points"] == sum(u["report"]["scans"] for u in done)
    assert magnetic["count"] == len(done)
    assert magnetic["items"][-1]["n_samples"] == sum(u["report"]["magnetic_samples"] for u in done)
