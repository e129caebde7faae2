"""The service's wheel holds the service only, and the service runs from it alone: no
research harness (``lab``, its dataset readers), no simulator (``client_sim``)."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import sysconfig
import time
import venv
import zipfile
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def checkout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of the checkout's files (those git tracks or would), to build wheels from
    without writing into the checkout."""
    tracked = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    src = tmp_path_factory.mktemp("checkout")
    for name in filter(None, (t.decode() for t in tracked)):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    return src


def _wheel(project: Path, out: Path, name: str) -> Path:
    """``pip wheel`` of ``project``; a failure fails the test (set
    ``INDOORPOS_TEST_ALLOW_NO_WHEEL=1`` on a machine that cannot reach a package index to
    skip instead)."""
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), project],
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        message = f"pip could not build the {name} wheel: {done.stderr[-800:]}"
        if os.environ.get("INDOORPOS_TEST_ALLOW_NO_WHEEL") == "1":
            pytest.skip(message)
        pytest.fail(message)
    (wheel,) = out.glob(f"{name.replace('-', '_')}-*.whl")
    return wheel


@pytest.fixture(scope="module")
def service_wheel(checkout: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _wheel(checkout, tmp_path_factory.mktemp("wheels"), "indoorpos")


def _packages_under(folder: Path, top: str) -> set[str]:
    """The packages of a folder whose package root it is (every directory holding an
    ``__init__.py``), as dotted names under ``top``."""
    return {
        ".".join([top, *init.parent.relative_to(folder).parts])
        for init in folder.rglob("__init__.py")
        if "build" not in init.relative_to(folder).parts
    }


@pytest.mark.parametrize(
    ("folder", "name"), [("lab", "indoorpos-lab"), ("client_sim", "indoorpos-sim")]
)
def test_the_lab_and_the_simulator_wheels_hold_every_package_of_theirs(
    checkout: Path, tmp_path: Path, folder: str, name: str
) -> None:
    wheel = _wheel(checkout / folder, tmp_path, name)
    names = zipfile.ZipFile(wheel).namelist()
    packages = {n.rsplit("/", 1)[0].replace("/", ".") for n in names if n.endswith("/__init__.py")}
    assert packages == _packages_under(checkout / folder, folder)
    modules = {n for n in names if n.endswith(".py")}
    assert modules == {
        f"{folder}/{p.relative_to(checkout / folder).as_posix()}"
        for p in (checkout / folder).rglob("*.py")
        if "build" not in p.relative_to(checkout / folder).parts  # what pip wheel leaves
    }
    assert not [n for n in names if n.startswith("server/")]


def test_the_wheel_holds_the_service_only(service_wheel: Path) -> None:
    names = zipfile.ZipFile(service_wheel).namelist()
    packages = {n.split("/")[0] for n in names if n.endswith(".py") and ".data/" not in n}
    assert packages == {"server"}
    # the database migrations travel with it, as data
    assert any(n.endswith("data/share/indoorpos/migrations/env.py") for n in names)
    assert any(n.endswith("migrations/versions/0001_initial_schema.py") for n in names)
    assert "server/app.py" in names
    assert "server/positioning/engines/auto.py" in names
    assert not [n for n in names if "/lab/" in n or "/datasets/" in n or "client_sim" in n]
    assert any(n.startswith("server/console/static/") for n in names)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def test_the_service_serves_from_its_wheel_alone(service_wheel: Path, tmp_path: Path) -> None:
    """A fresh environment holding the wheel, with the third-party packages of this one on
    its path (not its editable installs): the service's command runs, serves and answers,
    and neither the lab nor the simulator can be imported there."""
    env_dir = tmp_path / "env"
    venv.create(env_dir, with_pip=True)  # its own pip (bundled): this environment is not touched
    python = env_dir / "bin" / "python"
    site = Path(
        subprocess.run(
            [python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    pip: list[str | Path] = [python, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index"]
    subprocess.run([*pip, str(service_wheel)], check=True)
    # third-party packages from this environment: a path entry, so its .pth hooks (the
    # editable installs of the lab and the simulator) do not run
    (site / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    env.pop("PYTHONPATH", None)
    run: list[str | Path] = [env_dir / "bin" / "indoorpos"]  # the console script
    cwd = tmp_path  # not the checkout: its folders must not be importable
    blocked = subprocess.run(
        [python, "-c", "import lab.cli"], capture_output=True, text=True, cwd=cwd, env=env
    )
    assert blocked.returncode != 0
    assert "ModuleNotFoundError" in blocked.stderr
    blocked = subprocess.run(
        [python, "-c", "import client_sim"], capture_output=True, text=True, cwd=cwd, env=env
    )
    assert blocked.returncode != 0
    assert "ModuleNotFoundError" in blocked.stderr

    port = _free_port()
    env |= {"INDOORPOS_DATA_DIR": str(tmp_path / "data"), "INDOORPOS_ADMIN_KEY": "k" * 32}
    log = tmp_path / "serve.log"
    with log.open("w") as out:
        server = subprocess.Popen(
            [*run, "serve", "--host", "127.0.0.1", "--port", str(port)],
            cwd=cwd,
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + 60
        while True:
            assert server.poll() is None, log.read_text()
            try:
                answer = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1)
                break
            except httpx.TransportError:
                assert time.monotonic() < deadline, "the service did not start"
                time.sleep(0.2)
        assert answer.status_code == 200
        created = httpx.post(
            f"http://127.0.0.1:{port}/v1/sites",
            json={"name": "wheel"},
            headers={"Authorization": "Bearer " + "k" * 32},
            timeout=10,
        )
        assert created.status_code in (200, 201), created.text
    finally:
        server.terminate()
        server.wait(timeout=20)
