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


def test_an_empty_negative_or_endless_history_retention_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # past 36500 days (and inf, nan) the purge's cut-off would overflow a datetime:
    # `forever` keeps the history for good
    monkeypatch.setenv("INDOORPOS_HISTORY_RETENTION_DAYS", "36500")
    assert Settings().history_retention_days == 36_500
    for value in ("", "-1", "36501", "800000", "inf", "nan"):
        monkeypatch.setenv("INDOORPOS_HISTORY_RETENTION_DAYS", value)
        with pytest.raises(ValueError, match="history_retention_days"):
            Settings()
