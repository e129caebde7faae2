"""ILC evaluation: what the replayer is given (whole runs: tests/lab/cli/test_evaluate.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from lab import ilc_evaluation
from server.positioning.model.events import Event, Fix, ImuEvent

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SITE2 = DATA / "ilc20-sample" / "site2"
needs_data = pytest.mark.skipif(
    not SITE2.is_dir(), reason="../shared/data is not beside the project"
)


@needs_data
def test_evaluate_ilc_replays_imu_blocks_to_an_engine_that_reads_them(imu_engine: str) -> None:
    seen: dict[str, list[list[Event]]] = {}

    def capture(
        engine: str, _maps: object, _labelled: object, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        seen[engine] = traces
        return [[] for _ in traces]

    for engine in ("wknn", imu_engine):
        ilc_evaluation.evaluate_ilc(SITE2 / "F4", engine, replayer=capture)
    assert len(seen["wknn"]) == len(seen[imu_engine]) > 0
    for radio, everything in zip(seen["wknn"], seen[imu_engine], strict=True):
        assert not any(isinstance(e, ImuEvent) for e in radio)
        assert [e for e in everything if not isinstance(e, ImuEvent)] == radio
        blocks = [e for e in everything if isinstance(e, ImuEvent)]
        assert len(blocks) >= 5
        assert all(b.accel.shape[0] > 0 for b in blocks)
