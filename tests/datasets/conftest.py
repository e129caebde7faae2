"""Where the recorded datasets live: ``../shared/data/`` next to the project root.

The data is not part of the repository; a test that needs a dataset folder that is not
there is skipped with the path it looked for. ``raw_trace`` is the ILC sample trace the
reader and walk tests share; ``venue`` and ``log`` the IPIN dev venue and one of its logs.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from server.datasets.ilc_trace import IlcWalk, read_trace
from server.datasets.ipin import IpinVenue, read_venue
from server.datasets.ipin_log import IpinLog, read_log

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SAMPLE_ID = "5dd5206850e04e0006f56460"  # ILC site2/F4, also uncompressed in sample_raw/
IPIN_LOG = "IPIN2023_T3_TrainingTrial21_repetition03"  # SM-A520F, floor -2, 41,550 lines


def dataset_dir(name: str) -> Path:
    """``../shared/data/<name>``, or skip the test when it is absent."""
    path = DATA_DIR / name
    if not path.is_dir():
        pytest.skip(f"dataset folder ../shared/data/{name} is absent")
    return path


@pytest.fixture(scope="session")
def ilc_dir() -> Path:
    return dataset_dir("ilc20-sample")


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
def raw_path(ilc_dir: Path) -> Path:
    return ilc_dir / "sample_raw" / f"{SAMPLE_ID}.txt"


@pytest.fixture(scope="module")
def raw_lines(raw_path: Path) -> list[str]:
    return raw_path.read_text(encoding="utf-8").splitlines()


@pytest.fixture(scope="module")
def raw_trace(raw_path: Path) -> IlcWalk:
    return read_trace(raw_path)


@pytest.fixture(scope="module")
def venue(ipin_dir: Path) -> IpinVenue:
    return read_venue(ipin_dir)


@pytest.fixture(scope="module")
def log_path(ipin_dir: Path) -> Path:
    return ipin_dir / "logs" / f"{IPIN_LOG}.txt.xz"


@pytest.fixture(scope="module")
def log(log_path: Path, venue: IpinVenue) -> IpinLog:
    return read_log(log_path, venue.frame)
