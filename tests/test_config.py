"""Settings read from the environment."""

from __future__ import annotations

import pytest

from server.config import Settings


@pytest.mark.parametrize(
    ("value", "days"), [("forever", None), ("None", None), ("0", 0.0), ("7.5", 7.5)]
)
def test_the_history_is_kept_for_days_or_for_good(
    monkeypatch: pytest.MonkeyPatch, value: str, days: float | None
) -> None:
    monkeypatch.setenv("INDOORPOS_HISTORY_RETENTION_DAYS", value)
    assert Settings().history_retention_days == days


def test_an_empty_or_negative_history_retention_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    for value in ("", "-1"):
        monkeypatch.setenv("INDOORPOS_HISTORY_RETENTION_DAYS", value)
        with pytest.raises(ValueError, match="history_retention_days"):
            Settings()
