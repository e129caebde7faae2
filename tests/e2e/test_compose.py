"""docker-compose.yml scales: the api publishes no host port (so ``--scale api=3`` does
not collide) and is reached through the proxy, which routes a session's requests to one
replica (``deploy/haproxy.cfg``) and whose address alone the api trusts for
``X-Forwarded-For``; a one-shot ``migrate`` runs before api and worker start (so replicas
do not all migrate at once), and every health condition names a service with a health
check. Where HAProxy is installed, it accepts its configuration.

The checks run on the file as written (always) and on the configuration ``docker compose
config`` (or the older ``docker-compose config``) makes of it, where one is installed;
neither needs a Docker daemon nor the network.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]

ROOT = Path(__file__).resolve().parents[2]
COMPOSE_FILE = ROOT / "docker-compose.yml"
HAPROXY_CONFIG = ROOT / "deploy" / "haproxy.cfg"


def _compose_command() -> list[str] | None:
    """``docker compose`` or ``docker-compose``, whichever answers; None without either."""
    for command in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(command[0]) is None:
            continue
        probe = subprocess.run([*command, "version"], capture_output=True, timeout=60)
        if probe.returncode == 0:
            return command
    return None


def _config(command: list[str], **env: str) -> subprocess.CompletedProcess[str]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    args = [*command, "--file", str(COMPOSE_FILE), "config"]
    if command[:2] == ["docker", "compose"]:
        args += ["--format", "json"]
    return subprocess.run(args, env=base | env, capture_output=True, text=True, timeout=120)


def _fixed_host_port(port: Any) -> str | None:
    """The host port a ``ports`` entry pins, or None when Docker picks one per container.
    Short syntax ``[host_ip:][host_port:]container_port[/proto]``, or the long syntax."""
    if isinstance(port, dict):
        published = port.get("published")
        return str(published) if published not in (None, "") else None
    parts = str(port).split("/", 1)[0].split(":")
    host = parts[-2] if len(parts) >= 2 else ""
    return host or None


def _command(service: dict[str, Any]) -> str:
    command = service.get("command", "")
    return " ".join(command) if isinstance(command, list) else str(command)


def _conditions(service: dict[str, Any]) -> dict[str, str]:
    depends = service.get("depends_on", {})
    if isinstance(depends, list):  # the short syntax: service_started
        return dict.fromkeys(depends, "service_started")
    return {name: spec.get("condition", "service_started") for name, spec in depends.items()}


def _check(config: dict[str, Any]) -> None:
    services = config["services"]
    assert {"postgres", "redis", "migrate", "api", "worker"} <= set(services)

    migrate = services["migrate"]
    assert _command(migrate) == "indoorpos migrate"
    assert migrate.get("restart", "no") == "no"  # one shot: never restarted once it is done
    assert not migrate.get("ports")
    assert _conditions(migrate).get("postgres") == "service_healthy"

    for name, command in (("api", "indoorpos serve"), ("worker", "indoorpos worker")):
        service = services[name]
        assert _command(service).startswith(command), service
        assert "migrate" not in _command(service)  # only the one-shot service migrates
        assert _conditions(service).get("migrate") == "service_completed_successfully"

    pinned = [p for p in services["api"].get("ports", []) if _fixed_host_port(p) is not None]
    assert pinned == [], f"api replicas would collide on host ports {pinned}"
    assert "container_name" not in services["api"]  # a fixed name cannot scale either

    proxy = services["proxy"]
    assert [_fixed_host_port(p) for p in proxy["ports"]] == ["8000"]
    assert any("deploy/haproxy.cfg" in str(v) for v in proxy["volumes"])
    proxy_address = proxy["networks"]["default"]["ipv4_address"]
    for name in ("api", "worker", "migrate"):
        assert services[name]["environment"]["INDOORPOS_TRUSTED_PROXIES"] == proxy_address

    for name, service in services.items():
        for dependency, condition in _conditions(service).items():
            assert dependency in services, (name, dependency)
            if condition == "service_healthy":
                assert "healthcheck" in services[dependency], (name, dependency)


def test_the_compose_file_as_written_scales() -> None:
    _check(yaml.safe_load(COMPOSE_FILE.read_text()))


def test_the_ports_of_a_service_are_read_right() -> None:
    assert _fixed_host_port("8000") is None
    assert _fixed_host_port("127.0.0.1::8000") is None
    assert _fixed_host_port({"target": 8000}) is None
    assert _fixed_host_port({"target": 8000, "published": ""}) is None
    assert _fixed_host_port("8000:8000") == "8000"
    assert _fixed_host_port("127.0.0.1:8080:8000/tcp") == "8080"
    assert _fixed_host_port({"target": 8000, "published": "8000"}) == "8000"


def test_docker_compose_accepts_the_file_and_it_scales() -> None:
    command = _compose_command()
    if command is None:
        pytest.skip("neither `docker compose` nor `docker-compose` is installed")
    done = _config(command, INDOORPOS_ADMIN_KEY="not-a-real-key")
    assert done.returncode == 0, done.stderr
    config = json.loads(done.stdout) if done.stdout.lstrip().startswith("{") else None
    _check(config if config is not None else yaml.safe_load(done.stdout))
    # the admin key is required: without it compose refuses, saying so
    missing = _config(command)
    assert missing.returncode != 0
    assert "set an admin key" in missing.stderr


def test_haproxy_accepts_its_configuration() -> None:
    if shutil.which("haproxy") is None:
        pytest.skip("haproxy is not installed")
    done = subprocess.run(
        ["haproxy", "-c", "-f", str(HAPROXY_CONFIG)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stdout + done.stderr
