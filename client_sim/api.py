"""A small async client of the indoorpos HTTP API and its live WebSocket.

:class:`ApiClient` wraps one shared ``httpx.AsyncClient`` (whose ``base_url`` is the
service) and turns every non-2xx answer into :class:`ApiError`. Admin calls send the
admin key as a bearer token, device calls the session's token. :class:`LiveFixes` holds
a session's ``/v1/sessions/{id}/live`` socket open and counts the fixes pushed on it.

:meth:`LiveFixes.post_batch` posts batches over that socket and waits for each answer.

It speaks HTTP and WebSocket only, so it can drive any deployed stack.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections import Counter
from collections.abc import AsyncIterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import httpx
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, ConnectionClosedOK, WebSocketException

SURVEY_TIMEOUT_S = 300.0  # a survey rebuilds the radio map before it answers


class ApiError(Exception):
    """A non-2xx answer: ``status`` and the body's ``detail`` (or the text)."""

    def __init__(self, status: int, detail: Any, message: str | None = None) -> None:
        self.status = status
        self.detail = detail
        self.message = message if message is not None else str(detail)
        super().__init__(f"{status}: {self.message}")


@dataclass(frozen=True, slots=True)
class Session:
    id: str
    token: str
    site_id: str
    engine: str
    idle_timeout_s: int


@dataclass(frozen=True, slots=True)
class Fix:
    """The fields of a wire ``FixOut`` the simulator reads, and the whole of it in ``raw``."""

    t: int
    x_m: float
    y_m: float
    floor: int | None
    uncertainty_m: float
    source: str
    engine: str
    raw: Mapping[str, Any] = field(repr=False)

    @classmethod
    def from_wire(cls, body: Mapping[str, Any]) -> Fix:
        return cls(
            t=int(body["t"]),
            x_m=float(body["x_m"]),
            y_m=float(body["y_m"]),
            floor=None if body.get("floor") is None else int(body["floor"]),
            uncertainty_m=float(body.get("uncertainty_m", float("nan"))),
            source=str(body.get("source", "")),
            engine=str(body.get("engine", "")),
            raw=body,
        )


@dataclass(frozen=True, slots=True)
class BatchResult:
    seq: int
    replayed: bool
    fixes: tuple[Fix, ...]


def _raise_for_status(response: httpx.Response) -> None:
    if response.is_success:
        return
    try:
        body = response.json()
    except ValueError:
        raise ApiError(response.status_code, response.text) from None
    if isinstance(body, dict):
        message = body.get("message")
        raise ApiError(
            response.status_code,
            body.get("detail", body),
            message if isinstance(message, str) else None,
        )
    raise ApiError(response.status_code, body)


MAX_RETRY_AFTER_S = 60.0


def _retry_after_s(response: httpx.Response) -> float:
    """The wait a 429 asks for (``Retry-After`` seconds; 1 s when absent or unreadable)."""
    try:
        return min(max(float(response.headers.get("Retry-After", "1")), 0.1), MAX_RETRY_AFTER_S)
    except ValueError:
        return 1.0


def _bearer(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


class ApiClient:
    """The API calls the simulator makes, over a shared ``httpx.AsyncClient``."""

    def __init__(
        self,
        http: httpx.AsyncClient,
        admin_key: str | None = None,
        device_key: str | None = None,
        *,
        wait_when_limited: bool = False,
    ) -> None:
        """With ``wait_when_limited`` a call refused for a rate limit (429) is sent again
        after the ``Retry-After`` the service asked for (a replay that must go through);
        without it the 429 is raised, as a load test counts it."""
        self.http = http
        self._admin_key = admin_key
        self._device_key = device_key
        self._device_lock = asyncio.Lock()
        self._wait_when_limited = wait_when_limited

    @property
    def base_url(self) -> str:
        return str(self.http.base_url)

    async def _call(
        self,
        method: str,
        path: str,
        *,
        token: str | None,
        body: Any = None,
        time_limit_s: float | None = None,
    ) -> Any:
        while True:
            response = await self.http.request(
                method,
                path,
                json=body,
                headers=_bearer(token) if token is not None else None,
                timeout=time_limit_s if time_limit_s is not None else httpx.USE_CLIENT_DEFAULT,
            )
            if response.status_code != 429 or not self._wait_when_limited:
                break
            await asyncio.sleep(_retry_after_s(response))
        _raise_for_status(response)
        return response.json() if response.content else None

    async def _admin(
        self, method: str, path: str, body: Any, time_limit_s: float | None = None
    ) -> Any:
        if self._admin_key is None:
            raise ValueError("this client has no admin key")
        return await self._call(
            method, path, token=self._admin_key, body=body, time_limit_s=time_limit_s
        )

    # ------------------------------------------------------------ admin

    async def create_site(self, name: str) -> dict[str, Any]:
        result: dict[str, Any] = await self._admin("POST", "/v1/sites", {"name": name})
        return result

    async def create_building(self, site_id: str, name: str) -> dict[str, Any]:
        result: dict[str, Any] = await self._admin(
            "POST", f"/v1/sites/{site_id}/buildings", {"name": name}
        )
        return result

    async def create_floor(
        self, building_id: str, level: int, name: str | None = None
    ) -> dict[str, Any]:
        result: dict[str, Any] = await self._admin(
            "POST", f"/v1/buildings/{building_id}/floors", {"level": level, "name": name}
        )
        return result

    async def put_plan(self, floor_id: str, plan: Mapping[str, Any]) -> dict[str, Any]:
        result: dict[str, Any] = await self._admin("PUT", f"/v1/floors/{floor_id}/plan", plan)
        return result

    async def get(self, path: str) -> dict[str, Any]:
        """An admin read, e.g. ``/v1/sites/{id}``: the answer's JSON object."""
        result: dict[str, Any] = await self._admin("GET", path, None)
        return result

    async def post_survey(self, building_id: str, body: Mapping[str, Any]) -> dict[str, Any]:
        """``body`` is a ``SurveyIn``; the answer the new ``RadioMapRead``."""
        result: dict[str, Any] = await self._admin(
            "POST", f"/v1/buildings/{building_id}/survey", body, time_limit_s=SURVEY_TIMEOUT_S
        )
        return result

    async def list_radio_maps(self, building_id: str) -> dict[str, Any]:
        """The building's radio map versions (``RadioMapList``)."""
        result: dict[str, Any] = await self._admin(
            "GET", f"/v1/buildings/{building_id}/radio-maps", None
        )
        return result

    async def post_magnetic_survey(self, floor_id: str, body: Mapping[str, Any]) -> dict[str, Any]:
        """``body`` is a ``MagneticSurveyIn``; the answer the new ``MagneticMapRead``."""
        result: dict[str, Any] = await self._admin(
            "POST",
            f"/v1/floors/{floor_id}/magnetic-survey",
            body,
            time_limit_s=SURVEY_TIMEOUT_S,
        )
        return result

    async def post_upload(
        self,
        site_id: str,
        trace: bytes,
        *,
        floor: int | None = None,
        key: str | None = None,
        content_type: str = "text/plain",
    ) -> dict[str, Any]:
        """Upload a recorded trace (ILC 2.0 text); the answer the ``UploadRead``."""
        if self._admin_key is None:
            raise ValueError("this client has no admin key")
        params: dict[str, Any] = {"site_id": site_id}
        if floor is not None:
            params["floor"] = floor
        headers = {**_bearer(self._admin_key), "content-type": content_type}
        if key is not None:
            headers["idempotency-key"] = key
        response = await self.http.post(
            "/v1/uploads", params=params, content=trace, headers=headers, timeout=SURVEY_TIMEOUT_S
        )
        _raise_for_status(response)
        result: dict[str, Any] = response.json()
        return result

    async def get_upload(self, upload_id: str) -> dict[str, Any]:
        result: dict[str, Any] = await self._admin("GET", f"/v1/uploads/{upload_id}", None)
        return result

    # ------------------------------------------------------------ device

    async def device_key(self) -> str:
        """The key sessions are opened with: the one given, or a ``device`` key made once
        with the admin key."""
        async with self._device_lock:
            if self._device_key is None:
                body = {"name": "client simulator", "scopes": ["device"]}
                made = await self._admin("POST", "/v1/keys", body)
                self._device_key = str(made["key"])
            return self._device_key

    async def create_session(
        self,
        site_id: str,
        engine: str,
        params: Mapping[str, Any] | None = None,
        seed: int | None = None,
    ) -> Session:
        """Open a session; ``params`` override the engine's parameters (nested); ``seed``
        fixes its random stream (a replay of an in-process run)."""
        request: dict[str, Any] = {"site_id": site_id, "engine": engine}
        if params:
            request["params"] = dict(params)
        if seed is not None:
            request["seed"] = seed
        body = await self._call("POST", "/v1/sessions", token=await self.device_key(), body=request)
        return Session(
            id=str(body["id"]),
            token=str(body["token"]),
            site_id=str(body["site_id"]),
            engine=str(body["engine"]),
            idle_timeout_s=int(body["idle_timeout_s"]),
        )

    async def post_batch(
        self, session: Session, seq: int, events: Sequence[Mapping[str, Any]]
    ) -> BatchResult:
        body = await self._call(
            "POST",
            f"/v1/sessions/{session.id}/batches",
            token=session.token,
            body={"seq": seq, "events": list(events)},
        )
        return BatchResult(
            seq=int(body["seq"]),
            replayed=bool(body.get("replayed", False)),
            fixes=tuple(Fix.from_wire(f) for f in body.get("fixes", [])),
        )

    async def delete_session(self, session: Session) -> None:
        await self._call("DELETE", f"/v1/sessions/{session.id}", token=session.token)


def live_url(base_url: str, session: Session) -> str:
    """``ws(s)://.../v1/sessions/{id}/live`` under ``base_url`` (the token goes in a
    header, never in the URL)."""
    url = httpx.URL(base_url)
    scheme = {"http": "ws", "https": "wss"}.get(url.scheme, url.scheme)
    path = url.path.rstrip("/") + f"/v1/sessions/{session.id}/live"
    return str(url.copy_with(scheme=scheme, path=path, query=None))


class LiveFixes:
    """Counts what a session's live socket pushes, from a reader task, and posts batches
    over it.

    ``fixes_by_seq`` counts ``{"type": "fix"}`` messages per batch ``seq``; ``fix_messages``
    is their total; ``errors`` keeps the text of ``{"type": "error"}`` messages and of an
    unexpected close; ``closed`` is set once the socket is closed for whatever reason.
    While :meth:`post_batch` waits for its answer, an error message is that batch's answer
    (one batch at a time is in flight) and is not kept in ``errors``.
    """

    def __init__(self, ws: ClientConnection) -> None:
        self._ws = ws
        self.fixes_by_seq: Counter[int] = Counter()
        self.fix_messages = 0
        self.errors: list[str] = []
        self.closed = asyncio.Event()
        self.ready = asyncio.Event()
        self._changed = asyncio.Event()
        self._closing = False
        self._pending: asyncio.Future[BatchResult] | None = None
        self._pending_seq = 0
        self._task = asyncio.create_task(self._read())

    @classmethod
    @contextlib.asynccontextmanager
    async def open(
        cls, base_url: str, session: Session, open_timeout_s: float = 10.0
    ) -> AsyncIterator[LiveFixes]:
        """Connect, read in the background, and on exit close the socket and the reader."""
        async with connect(
            live_url(base_url, session),
            additional_headers={"Authorization": f"Bearer {session.token}"},
            open_timeout=open_timeout_s,
            close_timeout=2.0,
        ) as ws:
            live = cls(ws)
            try:
                # the server says "ready" once it follows the session; fixes of batches
                # posted after that are never missed
                ready = asyncio.ensure_future(live.ready.wait())
                closed = asyncio.ensure_future(live.closed.wait())
                await asyncio.wait(
                    {ready, closed}, timeout=open_timeout_s, return_when=asyncio.FIRST_COMPLETED
                )
                ready.cancel()
                closed.cancel()
                if not live.ready.is_set():
                    raise ConnectionError(f"live socket not ready: {'; '.join(live.errors)}")
                yield live
            finally:
                live._closing = True
                live._task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await live._task

    async def wait_for(self, expected: Mapping[int, int], timeout_s: float) -> bool:
        """Wait until at least ``expected[seq]`` fixes of every ``seq`` have arrived, the
        socket closed, or ``timeout_s`` passed; whether they all arrived."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout_s
        while True:
            if all(self.fixes_by_seq[s] >= n for s, n in expected.items()):
                return True
            remaining = deadline - loop.time()
            if remaining <= 0 or self.closed.is_set():
                return False
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), remaining)

    async def post_batch(
        self, seq: int, events: Sequence[Mapping[str, Any]], timeout_s: float
    ) -> BatchResult:
        """Send a batch over the socket and wait for its ``batch_result``; an ``error``
        message in the meantime raises :class:`ApiError`, a closed socket
        :class:`ConnectionError`, no answer in time :class:`TimeoutError`."""
        if self._pending is not None:
            raise RuntimeError("one batch at a time over a live socket")
        if self.closed.is_set():
            raise ConnectionError("live socket closed")
        self._pending = asyncio.get_running_loop().create_future()
        self._pending_seq = seq
        try:
            message = json.dumps({"type": "batch", "seq": seq, "events": list(events)})
            try:
                await self._ws.send(message)
            except ConnectionClosed as exc:
                raise ConnectionError(f"live socket closed: {exc}") from exc
            return await asyncio.wait_for(asyncio.shield(self._pending), timeout_s)
        finally:
            self._pending = None

    def _answer(self, result: BatchResult | BaseException, seq: int | None = None) -> bool:
        """Settle the batch in flight with an answer about ``seq`` (None: any); False when
        none is in flight or the answer is about another batch (a late one)."""
        pending = self._pending
        if pending is None or pending.done():
            return False
        if seq is not None and seq != self._pending_seq:
            return False
        if isinstance(result, BaseException):
            pending.set_exception(result)
        else:
            pending.set_result(result)
        return True

    async def _read(self) -> None:
        try:
            async for raw in self._ws:
                self._handle(raw)
        except ConnectionClosedOK:
            pass
        except (ConnectionClosed, WebSocketException, OSError) as exc:
            if not self._closing:
                self.errors.append(f"live socket: {type(exc).__name__}: {exc}")
        finally:
            self.closed.set()
            self._changed.set()
            self._answer(ConnectionError("live socket closed before the batch was answered"))

    def _handle(self, raw: str | bytes) -> None:
        try:
            message = json.loads(raw)
        except ValueError:
            self.errors.append(f"live socket: not JSON: {raw[:200]!r}")
            return
        kind = message.get("type") if isinstance(message, dict) else None
        if kind == "ready":
            self.ready.set()
        elif kind == "fix":
            self.fixes_by_seq[int(message.get("seq", 0))] += 1
            self.fix_messages += 1
            self._changed.set()
        elif kind == "batch_result":
            fixes = tuple(Fix.from_wire(f) for f in message.get("fixes", []))
            seq = int(message.get("seq", 0))
            if not self._answer(BatchResult(seq, bool(message.get("replayed", False)), fixes), seq):
                self.errors.append(f"live socket: an answer to seq {seq} nobody waits for")
        elif kind == "error":
            text = message.get("message") or message.get("detail")
            status = int(message.get("status", 0))
            about = message.get("seq")
            error = ApiError(status, message.get("detail", text), str(text))
            if not self._answer(error, int(about) if about is not None else None):
                self.errors.append(f"live socket: {status}: {text}")
