"""A real 3-node Redis Cluster on loopback ports for the tests (``tests/conftest.py``'s
fixture ``redis_cluster_url``), started with the machine's redis-server."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Iterator

import pytest

from tests.support.stores import REQUIRE_REDIS


def _free_ports(n: int) -> list[int]:
    """``n`` loopback ports free now, each with its cluster bus port (+10000) free too."""
    found: list[int] = []
    while len(found) < n:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port + 10000 < 65536 and port not in found:
            with socket.socket() as bus:
                try:
                    bus.bind(("127.0.0.1", port + 10000))
                except OSError:
                    continue
            found.append(port)
    return found


def start_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A 3-node Redis Cluster (no replicas) on loopback ports, started with the machine's
    redis-server and torn down after the run; its URL for ``redis_client``. Skipped
    without redis-server / redis-cli, unless ``INDOORPOS_TEST_REQUIRE_REDIS=1``."""
    server, cli = shutil.which("redis-server"), shutil.which("redis-cli")
    if server is None or cli is None:
        if REQUIRE_REDIS:
            pytest.fail("redis-server and redis-cli are needed for the Redis Cluster tests")
        pytest.skip("redis-server / redis-cli not installed")
    ports = _free_ports(3)
    root = tmp_path_factory.mktemp("redis-cluster")
    nodes = []
    try:
        for port in ports:
            folder = root / str(port)
            folder.mkdir()
            nodes.append(
                subprocess.Popen(
                    [
                        server,
                        "--port",
                        str(port),
                        "--bind",
                        "127.0.0.1",
                        "--cluster-enabled",
                        "yes",
                        "--cluster-config-file",
                        str(folder / "nodes.conf"),
                        "--dir",
                        str(folder),
                        "--save",
                        "",
                        "--appendonly",
                        "no",
                        "--logfile",
                        str(folder / "log"),
                    ],
                    stdout=subprocess.DEVNULL,
                )
            )
        for port in ports:  # each node answers before the cluster is made
            for _ in range(100):
                ping = subprocess.run(
                    [cli, "-p", str(port), "ping"], capture_output=True, text=True
                )
                if ping.stdout.strip() == "PONG":
                    break
                time.sleep(0.05)
        subprocess.run(
            [
                cli,
                "--cluster",
                "create",
                *(f"127.0.0.1:{p}" for p in ports),
                "--cluster-replicas",
                "0",
                "--cluster-yes",
            ],
            check=True,
            capture_output=True,
            timeout=60,
        )
        for _ in range(200):  # the slots are served once every node agrees
            info = subprocess.run(
                [cli, "-p", str(ports[0]), "cluster", "info"], capture_output=True, text=True
            )
            if "cluster_state:ok" in info.stdout:
                break
            time.sleep(0.05)
        else:
            pytest.fail("the Redis Cluster did not come up")
        yield f"redis+cluster://127.0.0.1:{ports[0]}"
    finally:
        for node in nodes:
            node.terminate()
        for node in nodes:
            node.wait(timeout=10)
