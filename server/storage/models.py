"""SQL schema: sites, buildings, floors, zones, emitters, survey points, radio and magnetic
map versions, uploads, sessions, engine settings, API keys, webhooks and their deliveries.
Ids are 32-character hex UUIDs."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


def new_id() -> str:
    return uuid.uuid4().hex


def utcnow() -> datetime:
    return datetime.now(UTC)


NAMING = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


class UTCDateTime(TypeDecorator[datetime]):
    """Timezone-aware UTC timestamps on every backend (SQLite stores them naive)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_result_value(
        self,
        value: datetime | None,
        dialect: Any,  # noqa: ARG002
    ) -> datetime | None:
        if value is not None and value.tzinfo is None:
            return value.replace(tzinfo=UTC)
        return value


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING)
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        datetime: UTCDateTime(),
        dict[str, Any]: JSON,
    }


class Site(Base):
    __tablename__ = "sites"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(200))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Building(Base):
    """A building with its local metric frame (x east, y north) and optional geo-reference."""

    __tablename__ = "buildings"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(String(200))
    origin_lat: Mapped[float | None] = mapped_column(Float)
    origin_lon: Mapped[float | None] = mapped_column(Float)
    rotation_rad: Mapped[float] = mapped_column(Float, default=0.0)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Floor(Base):
    __tablename__ = "floors"
    __table_args__ = (UniqueConstraint("building_id", "level"),)
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    building_id: Mapped[str] = mapped_column(
        ForeignKey("buildings.id", ondelete="CASCADE"), index=True
    )
    level: Mapped[int] = mapped_column(Integer)
    name: Mapped[str | None] = mapped_column(String(200))
    plan_geojson: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Zone(Base):
    """A named area of a floor (a shop, a room, a geofence): fixes say which zones they are
    in, and sessions entering or leaving one make events (``services.zones``)."""

    __tablename__ = "zones"
    floor_id: Mapped[str] = mapped_column(
        ForeignKey("floors.id", ondelete="CASCADE"), primary_key=True
    )
    id: Mapped[str] = mapped_column(String(64), primary_key=True)  # the feature's id
    name: Mapped[str] = mapped_column(String(200))
    # GeoJSON Polygon or MultiPolygon in metres of the floor frame
    geometry: Mapped[dict[str, Any]] = mapped_column(JSON)
    properties: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Emitter(Base):
    """A WiFi access point (BSSID) or BLE beacon heard in a building."""

    __tablename__ = "emitters"
    __table_args__ = (UniqueConstraint("building_id", "kind", "key"),)
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    building_id: Mapped[str] = mapped_column(
        ForeignKey("buildings.id", ondelete="CASCADE"), index=True
    )
    kind: Mapped[str] = mapped_column(String(8))  # "wifi" | "ble"
    key: Mapped[str] = mapped_column(String(128))  # lower-cased BSSID or beacon id
    floor_id: Mapped[str | None] = mapped_column(ForeignKey("floors.id", ondelete="SET NULL"))
    x_m: Mapped[float | None] = mapped_column(Float)
    y_m: Mapped[float | None] = mapped_column(Float)
    tx_power_dbm: Mapped[float | None] = mapped_column(Float)  # RSS at 1 m
    path_loss_exponent: Mapped[float | None] = mapped_column(Float)


class SurveyPoint(Base):
    """A labelled fingerprint: where the surveyor stood and what the phone measured."""

    __tablename__ = "survey_points"
    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    building_id: Mapped[str] = mapped_column(
        ForeignKey("buildings.id", ondelete="CASCADE"), index=True
    )
    floor_id: Mapped[str] = mapped_column(ForeignKey("floors.id", ondelete="CASCADE"))
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)
    t_ms: Mapped[int | None] = mapped_column(BigInteger)
    # {"wifi": [[bssid, rssi_dbm], ...], "ble": [[id, rssi_dbm], ...], "mag_ut": [x, y, z] | null}
    readings: Mapped[dict[str, Any]] = mapped_column(JSON)
    # the upload these readings came from (None: surveyed through the admin API)
    upload_id: Mapped[str | None] = mapped_column(
        ForeignKey("uploads.id", ondelete="CASCADE"), index=True
    )
    # the recorded walk the point was taken on (None: surveyed on its own), and the route
    # of walks repeated along one (held out together when the fix error is learned)
    walk: Mapped[str | None] = mapped_column(String(64))
    route: Mapped[str | None] = mapped_column(String(64))
    # the radio map version the point was first folded into (None: before migration 0009)
    radio_map_id: Mapped[str | None] = mapped_column(String(32), index=True)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class RadioMapVersion(Base):
    __tablename__ = "radio_maps"
    __table_args__ = (UniqueConstraint("building_id", "version"),)
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    building_id: Mapped[str] = mapped_column(
        ForeignKey("buildings.id", ondelete="CASCADE"), index=True
    )
    version: Mapped[int] = mapped_column(Integer)
    cell_m: Mapped[float] = mapped_column(Float)
    n_reference_points: Mapped[int] = mapped_column(Integer)
    n_emitters: Mapped[int] = mapped_column(Integer)
    n_survey_points: Mapped[int] = mapped_column(Integer)
    source: Mapped[str] = mapped_column(String(32), default="survey")
    # versions written since migration 0004 hold their arrays here (ReferencePoint and
    # RadioStat rows only for older ones)
    arrays: Mapped[bytes | None] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    # the current version is the one activated last (rollback: activate an older one)
    activated_at: Mapped[datetime] = mapped_column(default=utcnow)
    # the version this one was folded onto (None: the building's first)
    parent_id: Mapped[str | None] = mapped_column(String(32))
    # what the worker builds of the version beside its radio map (services.map_builds):
    # "pending" | "built" | "failed"; leased by one worker at a time
    build_status: Mapped[str] = mapped_column(
        String(16), default="pending", server_default="pending"
    )
    build_attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    build_leased_until: Mapped[datetime | None] = mapped_column()
    build_error: Mapped[str | None] = mapped_column(Text)
    build_seconds: Mapped[float | None] = mapped_column(Float)
    # the learned fix-error table (fix_error.FixErrorModel as JSON) and the other
    # artefacts (FAI emitter fits, floor graphs) as one compressed array container
    fix_error: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    artefacts: Mapped[bytes | None] = mapped_column(LargeBinary, deferred=True)


class ReferencePoint(Base):
    __tablename__ = "radio_map_rps"
    map_id: Mapped[str] = mapped_column(
        ForeignKey("radio_maps.id", ondelete="CASCADE"), primary_key=True
    )
    idx: Mapped[int] = mapped_column(Integer, primary_key=True)
    floor_id: Mapped[str] = mapped_column(ForeignKey("floors.id", ondelete="CASCADE"))
    x_m: Mapped[float] = mapped_column(Float)
    y_m: Mapped[float] = mapped_column(Float)


class RadioStat(Base):
    """Per reference point × emitter statistics of one radio map version."""

    __tablename__ = "radio_map_stats"
    map_id: Mapped[str] = mapped_column(
        ForeignKey("radio_maps.id", ondelete="CASCADE"), primary_key=True
    )
    rp_idx: Mapped[int] = mapped_column(Integer, primary_key=True)
    emitter_id: Mapped[int] = mapped_column(
        ForeignKey("emitters.id", ondelete="CASCADE"), primary_key=True
    )
    mean_dbm: Mapped[float] = mapped_column(Float)
    var_db2: Mapped[float] = mapped_column(Float)
    count: Mapped[int] = mapped_column(Integer)


class MagneticMapVersion(Base):
    """A regular grid over one floor; arrays stored compressed (dtype + shape + raw bytes)."""

    __tablename__ = "magnetic_maps"
    __table_args__ = (UniqueConstraint("floor_id", "version"),)
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    floor_id: Mapped[str] = mapped_column(ForeignKey("floors.id", ondelete="CASCADE"), index=True)
    version: Mapped[int] = mapped_column(Integer)
    origin_x_m: Mapped[float] = mapped_column(Float)
    origin_y_m: Mapped[float] = mapped_column(Float)
    resolution_m: Mapped[float] = mapped_column(Float)
    n_rows: Mapped[int] = mapped_column(Integer)
    n_cols: Mapped[int] = mapped_column(Integer)
    n_samples: Mapped[int] = mapped_column(Integer, default=0)
    known_cells: Mapped[int] = mapped_column(Integer, default=0)
    source: Mapped[str] = mapped_column(String(32), default="survey")
    arrays: Mapped[bytes] = mapped_column(LargeBinary)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    activated_at: Mapped[datetime] = mapped_column(default=utcnow)


class Upload(Base):
    """A crowdsourced trace waiting for, or folded into, a map version."""

    __tablename__ = "uploads"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    building_id: Mapped[str | None] = mapped_column(ForeignKey("buildings.id", ondelete="CASCADE"))
    idempotency_key: Mapped[str | None] = mapped_column(String(128), unique=True)
    status: Mapped[str] = mapped_column(String(16), default="queued")
    floor_level: Mapped[int | None] = mapped_column(Integer)  # the uploader's floor hint
    device_model: Mapped[str | None] = mapped_column(String(128))
    content_type: Mapped[str] = mapped_column(String(64))
    payload: Mapped[bytes] = mapped_column(LargeBinary)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    report: Mapped[dict[str, Any] | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class SessionContribution(Base):
    """A batch of a session whose device offered its walk for map building; the batches
    become one upload when the session ends."""

    __tablename__ = "session_contributions"
    session_id: Mapped[str] = mapped_column(String(32), primary_key=True)
    seq: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    payload: Mapped[bytes] = mapped_column(LargeBinary)  # storage.trace_codec encoding
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class SessionRecord(Base):
    """A positioning session as it was opened: what the session store's record is rebuilt
    from when the store lost it (``epoch``: the store's contents it was last held in)."""

    __tablename__ = "sessions"
    id: Mapped[str] = mapped_column(String(32), primary_key=True)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    engine: Mapped[str] = mapped_column(String(64))
    token_digest: Mapped[str] = mapped_column(String(64))
    entropy: Mapped[str] = mapped_column(String(32))  # 128 bits, hex
    contribute: Mapped[bool] = mapped_column(default=False)
    device_model: Mapped[str] = mapped_column(String(128), default="")
    # the engine parameters it runs with, as overrides of the defaults (JSON object)
    params: Mapped[dict[str, Any]] = mapped_column(JSON, default=dict, server_default="{}")
    epoch: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    # a batch at most every half idle timeout refreshes it (services.batches)
    last_active_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)
    ended_at: Mapped[datetime | None] = mapped_column()


class SessionFixes(Base):
    """The fixes of one applied batch of a session, as its answer held them: the session's
    history (``services.history``), kept ``history_retention_days`` from ``created_at``.
    No foreign key: rows are written a second or so after their batch, in bulk
    (``services.history_writer``), and outlive the session's live state."""

    __tablename__ = "session_fixes"
    session_id: Mapped[str] = mapped_column(String(32), primary_key=True)
    seq: Mapped[int] = mapped_column(BigInteger, primary_key=True)
    site_id: Mapped[str] = mapped_column(String(32), index=True)
    # the batch's fixes' time span (ms since the epoch): what a time window reads
    t_first_ms: Mapped[int] = mapped_column(BigInteger)
    t_last_ms: Mapped[int] = mapped_column(BigInteger)
    n_fixes: Mapped[int] = mapped_column(Integer)  # a page counts fixes before it reads them
    fixes: Mapped[bytes] = mapped_column(LargeBinary)  # a JSON array of FixOut
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)


class EngineSetting(Base):
    """A site's engine parameters: overrides of an engine's defaults (a JSON object, as a
    session's ``params``) that every new session of the site with that engine starts
    from."""

    __tablename__ = "engine_settings"
    site_id: Mapped[str] = mapped_column(
        ForeignKey("sites.id", ondelete="CASCADE"), primary_key=True
    )
    engine: Mapped[str] = mapped_column(String(64), primary_key=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    updated_at: Mapped[datetime] = mapped_column(default=utcnow, onupdate=utcnow)


class ApiKey(Base):
    """An API key; only its SHA-256 digest is stored. ``scopes`` is a space-separated set
    (``services.auth.SCOPES``); ``site_id`` None means every site."""

    __tablename__ = "api_keys"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    name: Mapped[str] = mapped_column(String(200))
    key_hash: Mapped[str] = mapped_column(String(64), unique=True)
    scopes: Mapped[str] = mapped_column(String(200), default="admin", server_default="admin")
    site_id: Mapped[str | None] = mapped_column(
        String(32), ForeignKey("sites.id", ondelete="CASCADE")
    )
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    rotated_at: Mapped[datetime | None] = mapped_column()
    revoked_at: Mapped[datetime | None] = mapped_column()


class Webhook(Base):
    """An operator's receiver of a site's events (``services.webhooks``): every delivery
    is signed with ``secret`` (kept here: the signature needs it)."""

    __tablename__ = "webhooks"
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    site_id: Mapped[str] = mapped_column(ForeignKey("sites.id", ondelete="CASCADE"), index=True)
    url: Mapped[str] = mapped_column(String(2000))
    events: Mapped[str] = mapped_column(String(200))  # space-separated event types
    secret: Mapped[str] = mapped_column(String(64))
    description: Mapped[str] = mapped_column(String(200), default="")
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class WebhookDelivery(Base):
    """One event owed to one webhook: ``pending`` until its receiver answers 2xx
    (``delivered``) or it runs out of attempts (``failed``); leased by one worker at a
    time. ``event_key`` names the event, so that an event made twice (a batch answered
    again) is owed once."""

    __tablename__ = "webhook_deliveries"
    __table_args__ = (
        UniqueConstraint("webhook_id", "event_key"),
        # what the workers poll for: the pending ones only, however many are settled
        Index(
            "ix_webhook_deliveries_due",
            "next_attempt_at",
            postgresql_where=text("status = 'pending'"),
            sqlite_where=text("status = 'pending'"),
        ),
        Index("ix_webhook_deliveries_webhook_created", "webhook_id", "created_at"),
    )
    id: Mapped[str] = mapped_column(String(32), primary_key=True, default=new_id)
    webhook_id: Mapped[str] = mapped_column(ForeignKey("webhooks.id", ondelete="CASCADE"))
    event_key: Mapped[str] = mapped_column(String(200))
    event_type: Mapped[str] = mapped_column(String(32))
    payload: Mapped[bytes] = mapped_column(LargeBinary)  # the JSON body sent
    status: Mapped[str] = mapped_column(String(16), default="pending")
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    next_attempt_at: Mapped[datetime] = mapped_column(default=utcnow)
    leased_until: Mapped[datetime | None] = mapped_column()
    last_error: Mapped[str | None] = mapped_column(Text)
    last_status_code: Mapped[int | None] = mapped_column(Integer)
    delivered_at: Mapped[datetime | None] = mapped_column()
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


Index("ix_survey_points_floor", SurveyPoint.floor_id)
