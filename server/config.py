"""Service settings, read from the environment with the prefix ``INDOORPOS_``.

With nothing set the service runs embedded: a SQLite file under ``data_dir`` and the
in-memory session store. Setting
``INDOORPOS_DATABASE_URL`` (a plain ``postgresql://user@host:port/db``) and
``INDOORPOS_REDIS_URL`` (``redis://host:port/db``) switches to the production shape.
"""

from __future__ import annotations

import ipaddress
import re
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

# an origin as a browser sends it: scheme, host and port, nothing after
ORIGIN = re.compile(r"^https?://[^\s/?#]+$")


def _comma_list(v: Any, check: Callable[[Any], str | None]) -> Any:
    """A comma-separated string (as an environment variable gives it) as its items, each
    passed to ``check``, which says what is wrong with it (None: nothing)."""
    if isinstance(v, str):
        v = [part.strip() for part in v.split(",") if part.strip()]
    for item in v if isinstance(v, list) else ():
        wrong = check(item)
        if wrong is not None:
            raise ValueError(f"{item!r} is not {wrong}")
    return v


def _not_network(item: Any) -> str | None:
    try:
        ipaddress.ip_network(item, strict=False)
    except (TypeError, ValueError):
        return "an address or a network"
    return None


def _not_origin(item: Any) -> str | None:
    if isinstance(item, str) and (item == "*" or ORIGIN.match(item)):
        return None
    return "an origin: scheme://host[:port] without a path or a trailing slash (or * for any)"


class Settings(BaseSettings):
    model_config = SettingsConfigDict(env_prefix="INDOORPOS_", extra="ignore")

    data_dir: Path = Field(Path(".indoorpos"), description="where the embedded SQLite file lives")
    database_url: str | None = Field(None, description="postgresql://... or sqlite:///...")
    redis_url: str | None = Field(
        None, description="redis://host:port/db, or redis+cluster://host:port for a cluster"
    )
    admin_key: SecretStr | None = Field(
        None, description="admin API key; keys made by `indoorpos keys create` work too"
    )
    session_idle_s: int = Field(1800, ge=10, description="sessions expire after this idle time")
    seq_wait_s: float = Field(
        2.0, ge=0, le=30, description="how long a batch waits for its predecessor seq"
    )
    max_event_skew_s: float = Field(
        86_400.0,
        gt=0,
        description="how far (either way) a batch's event times may lie from the newest "
        "event time the session has accepted, and how far apart one batch's events may "
        "lie; times are the phone's clock, checked against the session's own",
    )
    session_track_len: int = Field(
        200,
        ge=0,
        le=5000,
        description="fixes kept per session for GET /v1/sessions/{id}/track (the newest); "
        "0 keeps none",
    )
    replay_window: int = Field(
        16, ge=1, le=256, description="recent batch replies kept for retried seqs"
    )
    batch_concurrency: int = Field(
        4,
        ge=1,
        le=1024,
        description="batches one api process works on at once: a few let one batch's "
        "store round trips overlap another's work; many interleave on the event loop and "
        "stretch each other's latency (bench/performance.md)",
    )
    session_cache_size: int = Field(
        1024,
        ge=0,
        description="decoded session states kept per process (about 100 KB each for a "
        "3,000-particle cloud); 0 turns the cache off",
    )
    map_cache_size: int = Field(32, ge=1, description="site map sets kept in memory")
    rate_limits: bool = Field(
        True, description="refuse (429 + Retry-After) past the rate_* limits below"
    )
    rate_sessions_per_min: int = Field(
        60, ge=1, description="sessions opened per client address (per key: 100 times this)"
    )
    rate_locate_per_min: int = Field(
        600, ge=1, description="locate calls per client address (per key: 100 times this)"
    )
    rate_batches_per_min: int = Field(
        600, ge=1, description="batches per session (per client address: 10 times this)"
    )
    rate_uploads_per_min: int = Field(120, ge=1, description="uploads per key and per address")
    rate_auth_failures_per_min: int = Field(
        30, ge=1, description="failed authentications per client address"
    )
    live_query_token: bool = Field(
        False,
        description="deprecated: accept a session token as ?token= on the live socket "
        "(it is scrubbed from the logs); clients send a bearer header or an auth message",
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="browser origins (https://console.example.com) allowed to call the API "
        "from another origin, comma-separated; none by default. Credentials are bearer "
        "headers, never cookies",
    )
    trusted_proxies: Annotated[list[str], NoDecode] = Field(
        default_factory=list,
        description="addresses or networks (10.0.0.0/8) of the reverse proxies whose "
        "X-Forwarded-For names the client (rate limits count by that address), "
        "comma-separated; none by default: the connection's own address counts",
    )
    json_max_bytes: int = Field(
        4 * 1024 * 1024,
        ge=1024,
        description="largest JSON body of a device route (sessions, batches, locate); a "
        "batch at its limit of imu rows is about 3 MB. Bulk routes (uploads, surveys, "
        "plans) take upload_max_bytes",
    )
    upload_max_bytes: int = Field(
        64 * 1024 * 1024, ge=1024, description="largest upload, after decompression"
    )
    header_timeout_s: float = Field(
        10.0,
        gt=0,
        description="a request's headers arrive whole within this time of its first byte (the "
        "first request's: of the connection's opening), or the connection is answered 408 "
        "and closed; the idle time between requests is uvicorn's keep-alive timeout",
    )
    body_timeout_s: float = Field(
        20.0,
        gt=0,
        description="a request's body may take this long after its headers, plus one second "
        "per body_min_rate_bytes_s bytes received; past that, 408 and the connection closes",
    )
    body_min_rate_bytes_s: int = Field(
        500,
        ge=0,
        description="the rate a body must keep up after its body_timeout_s of grace (as "
        "Apache's mod_reqtimeout MinRate: each this many bytes received buy one more second): "
        "a 64 MiB upload over a slow phone link passes, a byte a second does not; 0: the "
        "whole body within body_timeout_s",
    )
    walk_retention_days: float | None = Field(
        None,
        gt=0,
        description="how long the recorded walks (survey points with their walks, the "
        "points of uploads) are kept after they were folded into a radio map; the maps "
        "keep their statistics, but a later build learns its fix-error table and graph "
        "moves only from the walks still kept. None (the default): kept for good",
    )
    history_retention_days: float | None = Field(
        30.0,
        ge=0,
        le=36_500,  # a hundred years; `forever` keeps them for good
        allow_inf_nan=False,
        description="how long every session's fixes are kept after they were made, for "
        "its history and exports (GET /v1/sessions/{id}/history, track.geojson, "
        "track.mfjson), whether or not the session ended; the worker deletes older ones. "
        "0 keeps none (nothing is written); none (or forever) keeps them for good; "
        "otherwise at most 36500 (a hundred years)",
    )
    upload_visibility_s: float = Field(
        120.0,
        gt=0,
        description="an upload a worker has held this long without settling it goes to "
        "another worker (longer than the slowest upload takes)",
    )
    upload_inertial_selection: bool = Field(
        False,
        description="use only the samples of an upload's steady walking (Mansour IV-A); "
        "off by default: on ILC site2 about a third of the walking time passes",
    )
    zone_dwell_s: float = Field(
        3.0,
        ge=0,
        le=3600,
        description="a session enters (or leaves) a zone once its fixes have stayed across "
        "the border this long, or this far (zone_dwell_m): a fix wobbling on a border "
        "makes no events",
    )
    zone_dwell_m: float = Field(
        3.0, ge=0, le=1000, description="the distance that confirms a zone border crossing"
    )
    webhook_retry_s: float = Field(
        10.0,
        gt=0,
        le=3600,
        description="a failed webhook delivery is tried again after this, doubled at each "
        "further failure (at most an hour)",
    )
    webhook_attempts: int = Field(
        10, ge=1, le=100, description="attempts of a webhook delivery before it is failed"
    )
    webhook_timeout_s: float = Field(
        10.0, gt=0, le=60, description="how long a webhook receiver may take to answer"
    )
    webhook_private_networks: bool = Field(
        False,
        description="let webhooks send to hosts that resolve to loopback, private or "
        "link-local addresses (off: an API key cannot point the worker at the service's "
        "own network)",
    )
    webhook_retention_days: float = Field(
        30.0,
        gt=0,
        description="deliveries delivered or failed are deleted this long after they were "
        "made (pending ones are kept until they settle)",
    )
    webhook_poll_s: float = Field(
        1.0, gt=0, le=60, description="how often a worker looks for webhook deliveries due"
    )
    log_format: Literal["json", "text"] = Field(
        "text", description="json: one JSON object per log line (server/logs.py)"
    )
    log_level: str = Field("INFO", description="DEBUG, INFO, WARNING, ERROR or CRITICAL")
    in_process_worker: bool | None = Field(
        None,
        description="run the upload worker inside the api process (default: when no Redis "
        "is configured, since the in-process queue is not shared between processes)",
    )

    @field_validator("database_url")
    @classmethod
    def _known_scheme(cls, v: str | None) -> str | None:
        if v is None or v == "":
            return None
        scheme = v.split("://", 1)[0].split("+", 1)[0]
        if scheme not in {"postgresql", "postgres", "sqlite"}:
            raise ValueError(f"unsupported database scheme {scheme!r}: use postgresql or sqlite")
        return v

    @field_validator("redis_url")
    @classmethod
    def _redis_scheme(cls, v: str | None) -> str | None:
        if v is None or v == "":
            return None
        if not v.startswith(("redis://", "rediss://", "unix://", "redis+cluster://")):
            raise ValueError(
                "redis_url must start with redis://, rediss://, unix:// or redis+cluster:// "
                "(a Redis Cluster: any of its nodes)"
            )
        return v

    @field_validator("history_retention_days", mode="before")
    @classmethod
    def _for_good(cls, v: Any) -> Any:
        """``none`` or ``forever``, as an environment variable says it."""
        if isinstance(v, str) and v.strip().lower() in {"none", "forever"}:
            return None
        return v

    @field_validator("trusted_proxies", mode="before")
    @classmethod
    def _proxies(cls, v: Any) -> Any:
        return _comma_list(v, _not_network)

    def proxy_options(self) -> dict[str, Any]:
        """uvicorn's options for X-Forwarded-For: read only from ``trusted_proxies``
        (uvicorn would otherwise believe any loopback client's)."""
        if not self.trusted_proxies:
            return {"proxy_headers": False}
        return {"proxy_headers": True, "forwarded_allow_ips": list(self.trusted_proxies)}

    @field_validator("cors_origins", mode="before")
    @classmethod
    def _origins(cls, v: Any) -> Any:
        v = _comma_list(v, _not_origin)
        return [o.lower() if o != "*" else o for o in v] if isinstance(v, list) else v

    @field_validator("log_level")
    @classmethod
    def _known_level(cls, v: str) -> str:
        level = v.upper()
        if level not in {"DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"}:
            raise ValueError("log_level must be DEBUG, INFO, WARNING, ERROR or CRITICAL")
        return level

    @property
    def resolved_database_url(self) -> str:
        """The configured database URL, or the embedded SQLite file."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'indoorpos.db').as_posix()}"

    @property
    def runs_worker_in_process(self) -> bool:
        if self.in_process_worker is not None:
            return self.in_process_worker
        return self.redis_url is None

    @property
    def embedded(self) -> bool:
        return self.database_url is None and self.redis_url is None


@lru_cache(maxsize=1)
def get_settings() -> Settings:
    return Settings()
