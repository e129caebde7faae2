"""A simulated pedestrian with a phone: the events the phone sends and where it really was.

The walker stays on one floor. It starts at a random node of the floor's walkable graph,
picks a random destination (a room centre or a corridor junction), walks the shortest
path there along graph edges, picks the next one, and so on. Straight steps: each step
heads for the next waypoint and is ``L ~ N(stride, sd)`` long, or ends at the waypoint
when that is nearer (so a walker turns at corners and never cuts through walls).
Collinear waypoints are merged, so only real turns shorten a step.

Per walker: mean step period ``~ U(0.55, 0.65)`` s and stride ``~ U(0.65, 0.75)`` m.
What the phone reports for step ``k`` of true length ``L_k`` and heading ``h_k``::

    length_k  = L_k + N(0, sigma_L^2)              sigma_L = 0.05 m
    heading_k = h_k + b_k + N(0, sigma_h^2)        sigma_h = 0.05 rad
    b_k       = b_{k-1} exp(-dt/tau) + N(0, sigma_b^2 (1 - exp(-2 dt/tau)))
                                                   sigma_b = 0.08 rad, tau = 30 s

(``b`` is a slowly varying heading bias, Ornstein-Uhlenbeck). A magnetometer reading in
the phone frame (flat, y forward along the true heading) comes with every step, a WiFi
scan every ``U(2, 4)`` s and a BLE scan every ``U(4, 10)`` s, each from the position at
its time (linear between step ends). Timestamps are the phone clock:
``t = t0_ms + round(1000 s)`` for ``s`` seconds since the walk began.

Pure: :meth:`Walker.events` yields wire-ready events with their truth and does no I/O; the
same seed gives the same walk.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from client_sim.building import Floor
from client_sim.magnetic import to_phone_frame
from client_sim.seeding import child
from client_sim.world import SyntheticWorld

FloatArray = NDArray[np.float64]

_MERGE_TURN_RAD = math.radians(5.0)


@dataclass(frozen=True, slots=True)
class WalkerParams:
    """Walker and phone behaviour (module docstring); ranges are drawn once per walker."""

    step_period_s: tuple[float, float] = (0.55, 0.65)
    step_period_sd_s: float = 0.02
    step_length_m: tuple[float, float] = (0.65, 0.75)
    step_length_sd_m: float = 0.03  # true stride-to-stride variation
    min_step_m: float = 0.25
    length_noise_sd_m: float = 0.05  # sigma_L
    heading_noise_sd_rad: float = 0.05  # sigma_h
    heading_bias_sd_rad: float = 0.08  # sigma_b
    heading_bias_tau_s: float = 30.0  # tau
    wifi_period_s: tuple[float, float] = (2.0, 4.0)
    ble_period_s: tuple[float, float] = (4.0, 10.0)


@dataclass(frozen=True, slots=True)
class Truth:
    """Where the walker really was at phone time ``t`` (ms) and which way it walked."""

    t: int
    x_m: float
    y_m: float
    level: int
    heading_rad: float


@dataclass(frozen=True, slots=True)
class TimedEvent:
    """A wire event (``{"type": ..., "t": ...}``), when it happens in seconds since the
    walk began, and the truth at that moment."""

    sim_s: float
    event: dict[str, Any]
    truth: Truth


class Walker:
    """One pedestrian on ``level`` of ``world``'s building.

    Parameters
    ----------
    world : SyntheticWorld
    level : int
    seed : numpy.random.SeedSequence
        Everything random about the walker derives from it (not mutated).
    t0_ms : int
        Phone clock when the walk begins.
    params : WalkerParams
    """

    def __init__(
        self,
        world: SyntheticWorld,
        level: int,
        seed: np.random.SeedSequence,
        t0_ms: int,
        params: WalkerParams | None = None,
    ) -> None:
        self.world = world
        self.level = level
        self.floor: Floor = world.building.floor(level)
        self.seed = seed
        self.t0_ms = t0_ms
        self.params = params if params is not None else WalkerParams()
        persona = child(seed, 0)
        self.step_period_s = float(persona.uniform(*self.params.step_period_s))
        self.stride_m = float(persona.uniform(*self.params.step_length_m))
        self.start_node = int(persona.choice(_destinations(self.floor)))
        self.start_xy = (
            float(self.floor.nodes[self.start_node, 0]),
            float(self.floor.nodes[self.start_node, 1]),
        )

    def t_ms(self, sim_s: float) -> int:
        """Phone clock at ``sim_s`` seconds into the walk."""
        return self.t0_ms + round(1000.0 * sim_s)

    def events(self) -> Iterator[TimedEvent]:
        """The walk's events in time order, without end; every call restarts the same walk."""
        p = self.params
        route = _Route(self.floor, self.start_node, child(self.seed, 1), p.min_step_m)
        motion = child(self.seed, 2)
        sensors = child(self.seed, 3)
        radio, magnetic = self.world.radio, self.world.magnetic
        level = self.level

        pos = np.array(self.start_xy, dtype=np.float64)
        t_s = 0.0
        heading = 0.0
        bias = float(motion.normal(0.0, p.heading_bias_sd_rad))
        next_wifi = float(sensors.uniform(0.0, 1.0))
        next_ble = float(sensors.uniform(0.0, p.ble_period_s[1]))
        while True:
            dt = max(0.3, float(motion.normal(self.step_period_s, p.step_period_sd_s)))
            stride = max(p.min_step_m, float(motion.normal(self.stride_m, p.step_length_sd_m)))
            new_pos = route.step(pos, stride)
            chord = new_pos - pos
            length = float(np.hypot(chord[0], chord[1]))
            heading = math.atan2(chord[0], chord[1])
            t_new = t_s + dt

            while min(next_wifi, next_ble) <= t_new:
                ts = min(next_wifi, next_ble)
                at = pos + (ts - t_s) / dt * chord
                truth = Truth(self.t_ms(ts), float(at[0]), float(at[1]), level, heading)
                if next_wifi <= next_ble:
                    rssi = radio.wifi.scan(at[None, :], level, sensors)[0]
                    event = {"type": "wifi", "t": truth.t, "readings": radio.wifi.readings(rssi)}
                    next_wifi += float(sensors.uniform(*p.wifi_period_s))
                else:
                    rssi = radio.ble.scan(at[None, :], level, sensors)[0]
                    event = {"type": "ble", "t": truth.t, "readings": radio.ble.readings(rssi)}
                    next_ble += float(sensors.uniform(*p.ble_period_s))
                yield TimedEvent(ts, event, truth)

            decay = math.exp(-dt / p.heading_bias_tau_s)
            bias = bias * decay + float(
                motion.normal(0.0, p.heading_bias_sd_rad * math.sqrt(1.0 - decay * decay))
            )
            reported_length = length + float(motion.normal(0.0, p.length_noise_sd_m))
            reported_heading = heading + bias + float(motion.normal(0.0, p.heading_noise_sd_rad))
            truth = Truth(self.t_ms(t_new), float(new_pos[0]), float(new_pos[1]), level, heading)
            step = {
                "type": "step",
                "t": truth.t,
                "length_m": round(min(3.0, max(0.05, reported_length)), 3),
                "heading_rad": round(_wrap(reported_heading), 5),
            }
            yield TimedEvent(t_new, step, truth)
            field = magnetic.sample(new_pos[None, :], level, sensors)
            mag = np.round(to_phone_frame(field, heading)[0], 2).tolist()
            yield TimedEvent(t_new, {"type": "mag", "t": truth.t, "field_ut": mag}, truth)
            pos, t_s = new_pos, t_new


class TruthTrack:
    """The truths of a walk, by phone time, to look up where the walker was at any ``t``."""

    def __init__(self) -> None:
        self._rows: list[tuple[int, float, float, int]] = []
        self._arrays: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None = None

    def __len__(self) -> int:
        return len(self._rows)

    def add(self, truth: Truth) -> None:
        """Append a truth; times must not decrease."""
        if self._rows and truth.t < self._rows[-1][0]:
            raise ValueError("truths must come in time order")
        self._rows.append((truth.t, truth.x_m, truth.y_m, truth.level))
        self._arrays = None

    def at(self, t_ms: int) -> tuple[float, float, int]:
        """Position (linear between truths, clamped at the ends) and level at ``t_ms``."""
        if not self._rows:
            raise LookupError("no truth yet")
        if self._arrays is None:
            a = np.array(self._rows, dtype=np.float64)
            self._arrays = (a[:, 0], a[:, 1], a[:, 2], a[:, 3])
        t, x, y, level = self._arrays
        i = int(np.clip(np.searchsorted(t, t_ms, side="right") - 1, 0, len(t) - 1))
        return float(np.interp(t_ms, t, x)), float(np.interp(t_ms, t, y)), int(level[i])


class _Route:
    """Waypoints ahead of the walker, extended with a new shortest path when they run out."""

    def __init__(self, floor: Floor, start: int, rng: np.random.Generator, min_step_m: float):
        self.floor = floor
        self.node = start
        self.rng = rng
        self.min_step_m = min_step_m
        self.adjacency = floor.neighbours()
        lengths = floor.edge_lengths_m
        self.weight = {
            (int(a), int(b)): float(w)
            for (a, b), w in zip(floor.edges.tolist(), lengths, strict=True)
        }
        self.weight.update({(b, a): w for (a, b), w in list(self.weight.items())})
        self.destinations = _destinations(floor)
        self.waypoints: deque[FloatArray] = deque()

    def step(self, pos: FloatArray, stride_m: float) -> FloatArray:
        """Where a step of ``stride_m`` from ``pos`` towards the next waypoint ends."""
        while True:
            if not self.waypoints:
                self._extend()
                continue
            delta = self.waypoints[0] - pos
            r = float(np.hypot(delta[0], delta[1]))
            if r >= self.min_step_m:
                break
            self.waypoints.popleft()
        if r <= stride_m:
            end: FloatArray = self.waypoints.popleft().copy()
            return end
        out: FloatArray = pos + stride_m / r * delta
        return out

    def _extend(self) -> None:
        options = self.destinations[self.destinations != self.node]
        goal = int(self.rng.choice(options))
        path = _shortest_path(self.adjacency, self.weight, self.node, goal)
        xy = self.floor.nodes[path]
        keep = [len(xy) - 1]
        for i in range(len(xy) - 2, 0, -1):  # merge collinear waypoints
            a, b = xy[i] - xy[i - 1], xy[keep[-1]] - xy[i]
            turn = abs(_wrap(math.atan2(b[0], b[1]) - math.atan2(a[0], a[1])))
            if turn > _MERGE_TURN_RAD:
                keep.append(i)
        self.waypoints.extend(xy[i] for i in reversed(keep))
        self.node = goal


def _destinations(floor: Floor) -> NDArray[np.int64]:
    """Room centres and corridor junctions: the nodes not of degree two."""
    degree = np.bincount(floor.edges.ravel(), minlength=len(floor.nodes))
    picks: NDArray[np.int64] = np.flatnonzero(degree != 2).astype(np.int64)
    return picks


def _shortest_path(
    adjacency: list[list[int]], weight: dict[tuple[int, int], float], start: int, goal: int
) -> list[int]:
    """Dijkstra over the walkable graph; node indices from ``start`` to ``goal``."""
    best = {start: 0.0}
    previous: dict[int, int] = {}
    heap = [(0.0, start)]
    while heap:
        d, node = heapq.heappop(heap)
        if node == goal:
            break
        if d > best[node]:
            continue
        for nxt in adjacency[node]:
            nd = d + weight[(node, nxt)]
            if nd < best.get(nxt, math.inf):
                best[nxt] = nd
                previous[nxt] = node
                heapq.heappush(heap, (nd, nxt))
    if goal not in best:
        raise ValueError(f"node {goal} cannot be reached from node {start}")
    path = [goal]
    while path[-1] != start:
        path.append(previous[path[-1]])
    return path[::-1]


def _wrap(angle: float) -> float:
    """Angle in (-pi, pi]."""
    return math.pi - (math.pi - angle) % (2.0 * math.pi)
