"""The api that ``indoorpos bench load`` (``load_bench``) walks its users against, and
the server-side figures it reads of it.

``ApiProcesses`` runs the api as it does in production -- ``indoorpos serve`` with ``k``
worker processes, sessions in Redis, maps in PostgreSQL, the access log and (unless the
bench's ``rate_limits`` is off) the rate limits on, with the allowances of a load
generator (``LOAD_GENERATOR_LIMITS``) -- as a child process of the bench, pinned (by
``taskset``) to the CPUs the bench gives it. Of it the bench reads:

* **CPU.** The api processes' CPU time (user + system, the process and its children,
  from ``/proc``): ``ApiProcesses.cpu_seconds``.
* **Latency.** The api's batch-duration histogram (``/metrics``, ``batch_buckets``):
  ``bucket_p99_ms`` is the bound of the first bucket holding 99 % of a level's batches,
  which leaves out the simulator's own delays (one api process only: each process keeps
  its own histogram).

Linux only (CPU times and the process tree from ``/proc``).
"""

from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
from prometheus_client.parser import text_string_to_metric_families

START_TIMEOUT_S = 60.0


class ApiProcesses:
    """``indoorpos serve`` with ``workers`` processes, as a child of this one: uvicorn as
    deployed (its HTTP protocol with the header deadline, the log setup, the access log
    on: an answered batch's line is DEBUG only, ``server.logs.QuietBatches``)."""

    def __init__(
        self,
        workers: int,
        env: dict[str, str],
        cpus: set[int] | None,
    ) -> None:
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        command = [
            sys.executable,
            "-c",
            "from server.cli.main import app; app()",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--workers",
            str(workers),
        ]

        if cpus is not None:  # the api and every process it starts stay on these CPUs
            command = ["taskset", "--cpu-list", ",".join(map(str, sorted(cpus))), *command]
        # its log (INFO, as deployed) in a file of its own, not over the bench's output
        self.log_path = Path(tempfile.mkstemp(prefix="indoorpos-bench-api-", suffix=".log")[1])
        with self.log_path.open("wb") as log:
            self.process = subprocess.Popen(
                command,
                env={**os.environ, **env},
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                start_new_session=True,  # its own process group: stop() ends the workers too
            )
        self._wait_ready(workers)

    def _wait_ready(self, workers: int) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(
                    f"the api exited with code {self.process.returncode} (its log: {self.log_path})"
                )
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2.0).status_code == 200 and (
                    len(_descendants(self.process.pid)) >= (workers if workers > 1 else 0)
                ):
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(f"the api did not answer on {self.url} within {START_TIMEOUT_S} s")

    def cpu_seconds(self) -> float:
        """User + system CPU time of the api process and its children so far."""
        return sum(_cpu_seconds(pid) for pid in [self.process.pid, *_descendants(self.process.pid)])

    def stop(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()


# Rate limits on, as deployed, with the allowances of one address raised as an operator
# would for a load generator: every simulated user comes from this machine, so the
# defaults (60 sessions and 6,000 batches a minute per address) would refuse the 61st
# user. Each batch still pays for the limits' buckets, as in production.
LOAD_GENERATOR_LIMITS = {
    "INDOORPOS_RATE_LIMITS": "true",
    "INDOORPOS_RATE_SESSIONS_PER_MIN": "1000000",
    "INDOORPOS_RATE_BATCHES_PER_MIN": "1000000",
}


BATCH_ROUTE = "/v1/sessions/{session_id}/batches"


def batch_buckets(url: str) -> dict[float, float]:
    """The api's answered batches by duration bucket (cumulative counts, by upper bound
    in seconds), from its ``/metrics``."""
    text = httpx.get(f"{url}/metrics", timeout=10.0).text
    buckets: dict[float, float] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            labels = sample.labels
            if (
                sample.name == "indoorpos_http_request_duration_seconds_bucket"
                and labels.get("route") == BATCH_ROUTE
                and labels.get("status") == "200"
            ):
                bound = float(labels["le"])
                buckets[bound] = buckets.get(bound, 0.0) + sample.value
    return buckets


def bucket_p99_ms(before: dict[float, float], after: dict[float, float]) -> float | None:
    """The bound of the first bucket holding 99 % of the batches answered in between."""
    counts = {bound: after[bound] - before.get(bound, 0.0) for bound in sorted(after)}
    total = counts.get(math.inf, 0.0)
    if total <= 0:
        return None
    return next(1000.0 * bound for bound, n in counts.items() if n >= 0.99 * total)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _descendants(pid: int) -> list[int]:
    """Every process below ``pid`` (from the parent links in ``/proc``)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        stat = _stat_fields(int(entry.name))
        if stat is not None:
            children.setdefault(int(stat[1]), []).append(int(entry.name))
    out: list[int] = []
    todo = [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def _stat_fields(pid: int) -> list[str] | None:
    """``/proc/<pid>/stat`` after the command name: state, ppid, ...; None once gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2 :].split()


def _cpu_seconds(pid: int) -> float:
    stat = _stat_fields(pid)
    if stat is None:
        return 0.0
    ticks = int(stat[11]) + int(stat[12])  # utime, stime (fields 14 and 15 of stat)
    return ticks / os.sysconf("SC_CLK_TCK")
