"""``indoorpos keys``: create, list, rotate and revoke, as an operator runs them."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path


def _keys(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    env |= {"INDOORPOS_DATA_DIR": str(tmp_path), "COLUMNS": "200"}
    command = [str(Path(sys.executable).parent / "indoorpos"), "keys", *args]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)


def test_an_operator_manages_keys_from_the_command_line(tmp_path: Path) -> None:
    made = _keys(tmp_path, "create", "--scope", "device", "--scope", "contribute")
    assert made.returncode == 0, made.stderr
    secret = made.stdout.strip().splitlines()[-1]
    assert secret.startswith("ipk_")
    assert "embedded SQLite database" in made.stdout  # which database it wrote to
    key_id = made.stdout.split("key id ", 1)[1].split()[0]

    listed = _keys(tmp_path, "list")
    assert listed.returncode == 0, listed.stderr
    assert key_id in listed.stdout
    assert "contribute device" in listed.stdout
    assert secret not in listed.stdout

    rotated = _keys(tmp_path, "rotate", key_id)
    assert rotated.returncode == 0, rotated.stderr
    assert rotated.stdout.strip().splitlines()[-1] not in (secret, "")

    assert _keys(tmp_path, "revoke", key_id).returncode == 0
    again = _keys(tmp_path, "revoke", key_id)
    assert again.returncode == 1
    assert "no live key" in again.stdout
    assert key_id not in _keys(tmp_path, "list").stdout

    bad = _keys(tmp_path, "create", "--scope", "root")
    assert bad.returncode == 1
    assert "unknown scopes" in bad.stdout
