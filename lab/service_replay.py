"""Replaying an evaluation through a running service, over HTTP, as phones and surveyors
would use it.

The training maps go up as a survey: every labelled scan a survey point at its
interpolated position (``survey_points``), with the floor plans and the magnetometer
samples (``magnetic_points``) when the engine reads them. With crowd maps the training
traces go up as crowd uploads instead, every waypoint dropped but the first and last
(``crowd_uploads``), and the service builds the maps from them (what became of them:
``summarise_crowd``). Each test trace becomes one session's batches.
"""

from __future__ import annotations

import asyncio
import lzma
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx

from client_sim.api import ApiClient
from client_sim.replay import REQUEST_TIMEOUT_S, keep_end_anchors, provision_site, replay_sessions
from lab.progress import Progress
from lab.replay import Replayer, batches
from lab.training_maps import LabelledField, LabelledScans, TrainingSurvey
from server.api.convert import fix_from_wire, to_wire
from server.positioning.engines.shared.site_maps import SiteMaps
from server.positioning.model.events import Event, Fix


def http_replayer(
    base_url: str,
    admin_key: str,
    progress: Progress,
    crowd_reports: list[dict[str, Any]] | None = None,
    params: Mapping[str, Any] | None = None,
    sites: dict[int, str] | None = None,
    seed: int | None = None,
) -> Replayer:
    """Replay through a running service: training scans go up as a survey (each point
    with its walk and route, with the floor plans and the magnetometer samples), the
    replay waits until the service's worker has built the maps, and each test trace
    becomes one session's batches. With ``crowd_reports`` the training traces go up as
    crowd uploads instead (every waypoint dropped but the first and last) and the service
    builds the maps from them; the uploads' final states are appended to the list. The
    sessions run with ``params`` (nested overrides of the engine's defaults). ``sites``
    remembers the site provisioned for each training set (by identity), so that replays of
    several engines over one training set share one site and one map build. With ``seed``
    every session draws the random stream an in-process replay of that seed draws
    (``replay.replay``); fresh entropy per session without."""
    provisioned = sites if sites is not None else {}

    offset_ms = 0

    async def replay(
        engine: str, maps: SiteMaps, training: TrainingSurvey, traces: list[list[Event]]
    ) -> list[list[dict[str, Any]]]:
        nonlocal offset_ms
        levels = [f.level for f in maps.floors]
        # a log timed from its own start goes up on a phone's clock (ms since the epoch)
        first = min((e.t_ms for t in traces for e in t), default=EPOCH_MS)
        first = min([first, *(e.t_ms for e in training.scans.events)])
        offset_ms = EPOCH_MS if first < EPOCH_MS // 2 else 0
        async with httpx.AsyncClient(base_url=base_url, timeout=REQUEST_TIMEOUT_S) as http:
            api = ApiClient(http, admin_key, wait_when_limited=True)
            site_id = provisioned.get(id(training))
            if site_id is None or crowd_reports is not None:
                uploads: list[tuple[int, bytes]] = []
                scans = training.scans
                if crowd_reports is not None:
                    uploads = crowd_uploads(training.traces, levels)
                    scans = LabelledScans()
                plans = {levels[i]: plan for i, plan in enumerate(training.plans) if plan}
                site_id = await provision_site(
                    api,
                    site_name=f"evaluation {maps.floors[0].building_id} {maps.version}",
                    levels=levels,
                    survey_points=survey_points(scans, levels, offset_ms),
                    plans=plans,
                    magnetic_points=magnetic_points(training.field, levels),
                    uploads=uploads,
                    on_progress=progress,
                    upload_reports=crowd_reports,
                )
                provisioned[id(training)] = site_id
            return await replay_sessions(
                api,
                site_id,
                engine,
                [
                    [[on_clock(to_wire(e), offset_ms) for e in b] for b in batches(t)]
                    for t in traces
                ],
                on_progress=progress,
                params=params,
                seed=seed,
            )

    def run(
        engine: str, maps: SiteMaps, training: TrainingSurvey, traces: list[list[Event]]
    ) -> list[list[Fix]]:
        fixes = asyncio.run(replay(engine, maps, training, traces))
        index = {f.level: i for i, f in enumerate(maps.floors)}
        return [
            [replace(fix_from_wire(f, index), t_ms=f["t"] - offset_ms) for f in path]
            for path in fixes
        ]

    return run


def crowd_uploads(
    traces: Sequence[tuple[int, Path]], levels: Sequence[int]
) -> list[tuple[int, bytes]]:
    """Each (floor index, file) trace as a crowd upload body by floor level: the trace
    text with every waypoint dropped but the first and last."""
    uploads = []
    for floor_index, path in traces:
        opener = lzma.open if path.suffix == ".xz" else open
        with opener(path, "rt", encoding="utf-8", errors="replace") as f:
            text = keep_end_anchors(f.read())
        uploads.append((levels[floor_index], text.encode()))
    return uploads


EPOCH_MS = 1_700_000_000_000
"""Where a replay puts the zero of a log timed from its own start (the IPIN logs)."""

_SAMPLED = ("accel", "gyro", "magnetic", "rotation", "pressure")


def on_clock(wire: dict[str, Any], offset_ms: int) -> dict[str, Any]:
    """A wire event with its time and its samples' times ``offset_ms`` later."""
    if not offset_ms:
        return wire
    out = {**wire, "t": wire["t"] + offset_ms}
    for name in _SAMPLED:
        if name in out:
            out[name] = [[row[0] + offset_ms, *row[1:]] for row in out[name]]
    return out


def survey_points(
    labelled: LabelledScans, levels: Sequence[int], offset_ms: int = 0
) -> list[dict[str, Any]]:
    """Every labelled scan as a survey point body (``SurveyPoint``): its position, floor
    level, time (``offset_ms`` later), readings, walk and route (where walks share one)."""
    survey = []
    for (x_m, y_m), floor, event, walk, route in zip(
        labelled.xy_m,
        labelled.floor,
        labelled.events,
        labelled.walk,
        labelled.route,
        strict=True,
    ):
        wire = to_wire(event)
        key = "wifi" if wire["type"] == "wifi" else "ble"
        point: dict[str, Any] = {
            "x_m": x_m,
            "y_m": y_m,
            "floor": levels[floor],
            "t": event.t_ms + offset_ms,
            key: wire["readings"],
            "walk": str(walk),
        }
        if route is not None:
            point["route"] = str(route)
        survey.append(point)
    return survey


def magnetic_points(
    field: LabelledField | None, levels: Sequence[int]
) -> dict[int, list[dict[str, float]]]:
    """The placed magnetometer samples as magnetic survey point bodies
    (``MagneticPointIn``) by floor level; none without samples."""
    magnetic: dict[int, list[dict[str, float]]] = {}
    if field is not None:
        for i, xy in field.xy_m.items():
            strengths = field.magnitude_ut[i]
            magnetic[levels[i]] = [
                {"x_m": x, "y_m": y, "magnitude_ut": b}
                for part, values in zip(xy, strengths, strict=True)
                for (x, y), b in zip(part.tolist(), values.tolist(), strict=True)
            ]
    return magnetic


def summarise_crowd(summary: dict[str, Any], reports: list[dict[str, Any]]) -> None:
    """What became of the crowd uploads, in the run's summary (the reference points and the
    per-floor magnetic coverage there describe the survey maps, so they are dropped)."""
    summary["map_source"] = "crowd"
    summary.pop("reference_points", None)  # of the survey maps, which this run did not use
    statuses: dict[str, int] = {}
    reasons: dict[str, int] = {}
    for r in reports:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
        reason = (r.get("report") or {}).get("reason")
        if reason:
            # numbers differ from walk to walk; the wording says what happened
            key = " ".join(w for w in reason.split() if not any(c.isdigit() for c in w))
            reasons[key] = reasons.get(key, 0) + 1
    summary["uploads"] = {"status": statuses, "reasons": reasons}
    for floor in summary.get("per_floor", {}).values():
        floor.pop("magnetic_coverage", None)
        floor.pop("magnetic_at_waypoints", None)
