"""Replaying recorded traces through an engine, causally, as a phone would post them.

Each trace is cut into batches of ``BATCH_MS`` of phone time: its WiFi and BLE scans, and
for engines that read raw motion samples its IMU samples in blocks of ``BATCH_MS``
(``trace_events``), and for engines that read magnetometer readings without raw samples
the field magnitude a phone would post (``PHONE_MAG_MS``). The engine never sees
waypoints or the true floor and searches every floor of the site.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lab.progress import Progress
from lab.training_maps import TrainingSurvey
from server.positioning.engines.registry import get_engine
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.events import Event, Fix, MagEvent, StepEvent
from server.positioning.model.walk import Walk
from server.positioning.motion.step_tracker import TrackerParams
from server.positioning.motion.walk_steps import walk_steps

# A phone posts about once a second; replay cuts each trace into batches of that span.
BATCH_MS = 1000


PHONE_STEPS = TrackerParams(heading="rotation")
"""How a phone that detects its own steps finds them in a recording (for engines that
read ``step`` events and not raw samples): the project's step tracker with the phone's
rotation-vector heading, as a phone SDK would run it."""

PHONE_MAG_MS = 100
"""A phone posting magnetometer readings (for engines that read ``mag`` events and not
raw samples) sends the mean field magnitude of each such span."""


def mag_events(trace: Walk, span_ms: int = PHONE_MAG_MS) -> list[MagEvent]:
    """The mean field magnitude of the trace's magnetometer samples per ``span_ms``, each
    at the last sample time of its span."""
    samples = trace.magnetic
    if samples.shape[0] == 0:
        return []
    strength = np.linalg.norm(samples[:, 1:4], axis=1)
    keep = np.isfinite(strength)
    t, strength = samples[keep, 0].astype(np.int64), strength[keep]
    if t.size == 0:
        return []
    span = (t - t[0]) // span_ms
    starts = np.flatnonzero(np.r_[True, span[1:] != span[:-1]])
    ends = np.r_[starts[1:], t.size]
    means = np.add.reduceat(strength, starts) / (ends - starts)
    return [
        MagEvent(int(t[e - 1]), magnitude_ut=float(m)) for e, m in zip(ends, means, strict=True)
    ]


# what the phone of a session posts where it is not what its engine reads: an ``auto``
# session's phone posts what the project's client posts, its scans and its detected steps
PHONE_POSTS = {"auto": frozenset({"step", "wifi", "ble", "pressure"})}


def trace_events(trace: Walk, engine: str) -> list[Event]:
    """What a phone running ``engine`` posts of a trace: its scans and, when the engine
    reads raw motion samples (``"imu"`` in its ``uses``), the IMU blocks too; an engine
    that reads steps but not raw samples gets the steps a phone would detect
    (``PHONE_STEPS``; those with a north-referenced heading), and one that reads ``mag``
    but not raw samples the magnitudes of ``mag_events``. What an engine would ignore is
    left out, so replay stays fast."""
    uses = PHONE_POSTS.get(engine, get_engine(engine).uses)
    events = trace.events(imu="imu" in uses, block_ms=BATCH_MS, pressure="pressure" in uses)
    if "mag" in uses and "imu" not in uses:
        events += mag_events(trace)
    if "step" in uses and "imu" not in uses:
        steps = walk_steps(trace, PHONE_STEPS)
        events += [
            StepEvent(t, length, heading)
            for t, length, heading in zip(
                steps.t_ms.tolist(), steps.length_m.tolist(), steps.north_rad.tolist(), strict=True
            )
            if math.isfinite(heading)
        ]
    events.sort(key=lambda e: e.t_ms)  # stable: the scans' and blocks' order is kept
    return events


def batches(events: Sequence[Event], batch_ms: int = BATCH_MS) -> list[list[Event]]:
    """Cut a time-ordered event list into consecutive spans of ``batch_ms`` phone time."""
    out: list[list[Event]] = []
    start: int | None = None
    for event in events:
        if start is None or event.t_ms >= start + batch_ms:
            out.append([])
            start = event.t_ms
        out[-1].append(event)
    return out


def replay(
    engine: str, events: Sequence[Event], maps: SiteMaps, seed: int, params: Any = None
) -> list[Fix]:
    """Run an engine over a trace batch by batch, as the service would (with its default
    parameters unless ``params`` is given)."""
    spec = get_engine(engine)
    params = spec.params() if params is None else params
    state = spec.start(params)
    fixes: list[Fix] = []
    for seq, batch in enumerate(batches(events), start=1):
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(seq,)))
        state, new = spec.step(state, batch, maps, params, rng)
        fixes += new
    return fixes


# Replays test traces (a list of time-ordered event lists) through an engine, given the
# training maps and what they were built from (``TrainingSurvey``); one fix list per trace.
Replayer = Callable[[str, SiteMaps, TrainingSurvey, list[list[Event]]], list[list[Fix]]]


def in_process_replayer(
    seed: int, progress: Progress | None = None, params: Any = None
) -> Replayer:
    def run(
        engine: str, maps: SiteMaps, _survey: TrainingSurvey, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        out = []
        for done, events in enumerate(traces, start=1):
            out.append(replay(engine, events, maps, seed=seed, params=params))
            if progress:
                progress("replay", done, len(traces))
        return out

    return run
