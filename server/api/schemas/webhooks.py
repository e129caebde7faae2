"""Webhooks of a site and what was delivered to them."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import AnyHttpUrl, Field, UrlConstraints

from server.api.schemas.common import Strict, StrictIn
from server.api.schemas.pages import NextCursor, PageCount

EventType = Literal[
    "zone.enter",
    "zone.exit",
    "navigation.rerouted",
    "navigation.floor_change",
    "navigation.arrived",
]
EVENT_TYPES: tuple[EventType, ...] = (
    "zone.enter",
    "zone.exit",
    "navigation.rerouted",
    "navigation.floor_change",
    "navigation.arrived",
)
DeliveryStatus = Literal["pending", "delivered", "failed"]
WebhookUrl = Annotated[AnyHttpUrl, UrlConstraints(max_length=2000)]


class WebhookCreate(StrictIn):
    url: WebhookUrl = Field(
        description="where the events are POSTed (http or https; a public address unless "
        "INDOORPOS_WEBHOOK_PRIVATE_NETWORKS is set)"
    )
    events: list[EventType] = Field(
        default_factory=lambda: list(EVENT_TYPES), min_length=1, max_length=10
    )
    description: Annotated[str, Field(max_length=200)] = ""


class WebhookRead(Strict):
    id: str
    site_id: str
    url: str
    events: list[EventType]
    description: str
    created_at: datetime
    deliveries: dict[str, int] = Field(
        default_factory=dict, description="deliveries by status: pending, delivered, failed"
    )
    last_error: str | None = Field(None, description="the newest failed attempt's error")


class WebhookCreated(WebhookRead):
    secret: str = Field(description="signs every delivery (X-Indoorpos-Signature); shown this once")


class WebhookList(Strict):
    items: list[WebhookRead]
    count: PageCount


class DeliveryRead(Strict):
    id: str
    event_type: str
    status: DeliveryStatus
    attempts: int
    next_attempt_at: datetime | None = Field(description="pending: when it is tried next")
    last_status_code: int | None
    last_error: str | None
    delivered_at: datetime | None
    created_at: datetime
    payload: dict[str, Any] = Field(description="the body sent")


class DeliveryList(Strict):
    items: list[DeliveryRead]
    count: PageCount
    next_cursor: NextCursor
