"""The UJI and IPIN datasets the readers' tests read: their folders (skipped when absent,
``tests.support.datasets``), the IPIN dev venue and one of its logs. The ILC sample
trace's fixtures (``ilc_dir``, ``raw_trace``, ...) are in ``tests/conftest.py``."""

from __future__ import annotations

from pathlib import Path

import pytest

from lab.datasets.ipin import IpinVenue, read_venue
from lab.datasets.ipin_log import IpinLog, read_log
from tests.support.datasets import IPIN_LOG, dataset_dir


@pytest.fixture(scope="session")
def uji_dir() -> Path:
    return dataset_dir("ujiindoorloc")


@pytest.fixture(scope="session")
def longterm_dir() -> Path:
    return dataset_dir("uji-longterm-wifi")


@pytest.fixture(scope="session")
def ipin_dir() -> Path:
    return dataset_dir("ipin2023-track3-dev")


@pytest.fixture(scope="module")
def venue(ipin_dir: Path) -> IpinVenue:
    return read_venue(ipin_dir)


@pytest.fixture(scope="module")
def log_path(ipin_dir: Path) -> Path:
    return ipin_dir / "logs" / f"{IPIN_LOG}.txt.xz"


@pytest.fixture(scope="module")
def log(log_path: Path, venue: IpinVenue) -> IpinLog:
    return read_log(log_path, venue.frame)
