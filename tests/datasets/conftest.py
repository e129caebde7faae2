"""Where the recorded datasets live: ``../shared/data/`` next to the project root.

The data is not part of the repository; a test that needs a dataset folder that is not
there is skipped with the path it looked for.
"""

from __future__ import annotations

from pathlib import Path

import pytest

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"


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
