"""Where the recorded datasets live: ``../shared/data/`` next to the project root.

The data is not part of the repository; a test that needs a dataset folder that is not
there is skipped with the path it looked for (``dataset_dir``). The fixtures on these
folders are in ``tests/conftest.py`` (the ILC sample trace, which readers, walks and
storage tests share) and ``tests/lab/datasets/conftest.py`` (UJI and IPIN).
"""

from __future__ import annotations

from pathlib import Path

import pytest

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SAMPLE_ID = "5dd5206850e04e0006f56460"  # ILC site2/F4, also uncompressed in sample_raw/
IPIN_LOG = "IPIN2023_T3_TrainingTrial21_repetition03"  # SM-A520F, floor -2, 41,550 lines


def dataset_dir(name: str) -> Path:
    """``../shared/data/<name>``, or skip the test when it is absent."""
    path = DATA_DIR / name
    if not path.is_dir():
        pytest.skip(f"dataset folder ../shared/data/{name} is absent")
    return path
