"""What ``indoorpos bench load`` reads of the api under load (the measuring itself is a
benchmark)."""

from __future__ import annotations

import math

from lab.load_bench_api import bucket_p99_ms


def test_the_servers_p99_is_the_bound_of_the_bucket_holding_99_percent() -> None:
    before = {0.005: 10.0, 0.05: 10.0, 0.1: 10.0, math.inf: 10.0}
    # 1,000 batches since: 980 within 5 ms, 15 more within 50 ms, the last 5 within 100 ms
    after = {0.005: 990.0, 0.05: 1005.0, 0.1: 1010.0, math.inf: 1010.0}
    assert bucket_p99_ms(before, after) == 50.0
    assert bucket_p99_ms(after, after) is None  # no batch in between
