"""Which database ``indoorpos keys`` and ``indoorpos migrate`` act on, said with the
password masked, and a database that cannot be reached said in one line on stderr."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from server.cli.output import masked_url

SECRET = "hunter2-not-a-real-one"
PRODUCTION_URL = os.environ.get("INDOORPOS_DATABASE_URL", "")


def _indoorpos(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """The command as an operator runs it: none of our settings but ``env``, its embedded
    data in ``tmp_path``, a wide terminal (so rich does not wrap the lines)."""
    base = {k: v for k, v in os.environ.items() if not k.startswith("INDOORPOS_")}
    base |= {"INDOORPOS_DATA_DIR": str(tmp_path), "COLUMNS": "400"}
    command = [str(Path(sys.executable).parent / "indoorpos"), *args]
    return subprocess.run(
        command, env=base | env, capture_output=True, text=True, timeout=120, cwd=tmp_path
    )


def _closed_port() -> int:
    """A loopback port nothing listens on (bound, then let go)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _one_error_line(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == 1, (result.stdout, result.stderr)
    assert "Traceback" not in result.stderr + result.stdout
    lines = result.stderr.splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: ")
    assert SECRET not in result.stderr + result.stdout
    return lines[0]


@pytest.mark.parametrize(
    ("url", "shown"),
    [
        (
            f"postgresql://indoorpos:{SECRET}@db.internal:5432/indoorpos",
            "postgresql://indoorpos:***@db.internal:5432/indoorpos",
        ),
        ("postgresql://postgres@127.0.0.1:5432/test", "postgresql://postgres@127.0.0.1:5432/test"),
        (
            f"postgresql://u:{SECRET}@[::1]:5432/db?sslmode=require&password={SECRET}",
            "postgresql://u:***@[::1]:5432/db?sslmode=require&password=***",
        ),
        (
            f"postgresql:///db?host=/run/postgresql&PASSWORD={SECRET}",
            "postgresql:///db?host=/run/postgresql&PASSWORD=***",
        ),
        ("sqlite:///data/indoorpos.db", "sqlite:///data/indoorpos.db"),
        ("sqlite:////srv/a@b/indoorpos.db", "sqlite:////srv/a@b/indoorpos.db"),
        ("not a url", "not a url"),
    ],
)
def test_masked_url_hides_only_the_password(url: str, shown: str) -> None:
    assert masked_url(url) == shown


def test_keys_create_names_the_embedded_database_and_its_file(tmp_path: Path) -> None:
    made = _indoorpos(tmp_path, "keys", "create", "--scope", "device")
    assert made.returncode == 0, made.stderr
    db_file = (tmp_path / "indoorpos.db").resolve()
    assert db_file.is_file()
    assert f"the embedded SQLite database sqlite:///{db_file.as_posix()}" in made.stdout
    assert "INDOORPOS_DATABASE_URL is not set" in made.stdout
    assert made.stdout.strip().splitlines()[-1].startswith("ipk_")  # the key, on its own


def test_keys_create_names_a_configured_database(tmp_path: Path) -> None:
    url = f"sqlite:///{(tmp_path / 'elsewhere' / 'keys.db').as_posix()}"
    made = _indoorpos(tmp_path, "keys", "create", INDOORPOS_DATABASE_URL=url)
    assert made.returncode == 0, made.stderr
    assert f"in the database {url};" in made.stdout
    assert "embedded" not in made.stdout
    assert not (tmp_path / "indoorpos.db").exists()  # nothing went to the embedded one


@pytest.mark.skipif(
    not PRODUCTION_URL.startswith("postgres"), reason="needs the suite's PostgreSQL"
)
def test_keys_create_masks_the_password_of_a_postgresql_url(tmp_path: Path) -> None:
    # a password in the URL; the suite's server lets the test user in without one
    scheme, rest = PRODUCTION_URL.split("://", 1)
    user, host = rest.split("@", 1)
    url = f"{scheme}://{user.split(':', 1)[0]}:{SECRET}@{host}"
    made = _indoorpos(tmp_path, "keys", "create", INDOORPOS_DATABASE_URL=url)
    if made.returncode != 0 and "password" in made.stderr.lower():
        pytest.skip("the suite's PostgreSQL checks passwords")
    assert made.returncode == 0, made.stderr
    assert f"in the database {masked_url(url)};" in made.stdout
    assert SECRET not in made.stdout + made.stderr


def test_migrate_against_a_server_that_does_not_answer_is_one_line(tmp_path: Path) -> None:
    port = _closed_port()
    url = f"postgresql://indoorpos:{SECRET}@127.0.0.1:{port}/indoorpos"
    line = _one_error_line(_indoorpos(tmp_path, "migrate", INDOORPOS_DATABASE_URL=url))
    assert line.startswith(
        f"error: cannot migrate the database postgresql://indoorpos:***@127.0.0.1:{port}/indoorpos:"
    )
    assert "ConnectionRefusedError" in line or "OSError" in line


def test_keys_create_against_a_server_that_does_not_answer_is_one_line(tmp_path: Path) -> None:
    url = f"postgresql://indoorpos:{SECRET}@127.0.0.1:{_closed_port()}/indoorpos"
    made = _indoorpos(tmp_path, "keys", "create", INDOORPOS_DATABASE_URL=url)
    assert "cannot migrate the database postgresql://indoorpos:***@" in _one_error_line(made)
    assert made.stdout == ""  # no key was printed


@pytest.mark.skipif(
    not PRODUCTION_URL.startswith("postgres"), reason="needs the suite's PostgreSQL"
)
def test_migrate_to_a_database_that_does_not_exist_is_one_line(tmp_path: Path) -> None:
    missing = f"indoorpos_missing_{uuid.uuid4().hex[:8]}"
    url = PRODUCTION_URL.rsplit("/", 1)[0] + f"/{missing}"
    line = _one_error_line(_indoorpos(tmp_path, "migrate", INDOORPOS_DATABASE_URL=url))
    assert f'database "{missing}" does not exist' in line


def test_migrate_to_a_sqlite_file_that_cannot_be_made_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("not a directory")
    url = f"sqlite:///{(tmp_path / 'a-file' / 'indoorpos.db').as_posix()}"
    line = _one_error_line(_indoorpos(tmp_path, "migrate", INDOORPOS_DATABASE_URL=url))
    assert line.startswith(f"error: cannot migrate the database {url}: ")


def test_migrate_with_a_bad_database_url_names_the_variable(tmp_path: Path) -> None:
    url = f"mysql://indoorpos:{SECRET}@db/indoorpos"
    line = _one_error_line(_indoorpos(tmp_path, "migrate", INDOORPOS_DATABASE_URL=url))
    assert line.startswith("error: INDOORPOS_DATABASE_URL: ")
    assert "unsupported database scheme 'mysql'" in line


def test_migrate_names_the_database_it_brought_up_to_date(tmp_path: Path) -> None:
    done = _indoorpos(tmp_path, "migrate")
    assert done.returncode == 0, done.stderr
    assert "schema up to date on sqlite:///" in done.stdout
