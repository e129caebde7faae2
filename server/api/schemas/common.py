"""Scalar types and base models every wire model shares."""

from __future__ import annotations

from typing import Annotated

from pydantic import AfterValidator, BaseModel, ConfigDict, Field
from pydantic import (
    Strict as StrictMode,
)

FiniteFloat = Annotated[float, StrictMode(), Field(allow_inf_nan=False)]
# a phone's clock in this century: a time of 0 (1970) or 2**53 (year 287,000) is a bug in
# the client, not a time (and stays far inside int64 and exact as a float)
EARLIEST_MS = 946_684_800_000  # 2000-01-01T00:00:00Z
LATEST_MS = 4_102_444_800_000  # 2100-01-01T00:00:00Z
TimestampMs = Annotated[
    int,
    StrictMode(),
    Field(
        ge=EARLIEST_MS,
        lt=LATEST_MS,
        description="milliseconds since the epoch, in 2000-2099",
    ),
]
# local coordinates: a building frame is never 100 km across
Coordinate = Annotated[float, StrictMode(), Field(ge=-100_000, le=100_000, allow_inf_nan=False)]
# ids we hand out are 32 hex characters
ID_PATTERN = r"^[0-9a-f]{32}$"  # the ids this service hands out
Id = Annotated[str, Field(pattern=ID_PATTERN, description="an id this service made")]
# emitter ids: printable ASCII without spaces (BSSIDs, "uuid:major:minor")
EmitterId = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[!-~]+$")]


def _plain_text(value: str) -> str:
    # C0 and C1 controls (ANSI escapes start with ESC or CSI), unpaired surrogates
    if any(ord(c) < 32 or 127 <= ord(c) <= 159 or 0xD800 <= ord(c) <= 0xDFFF for c in value):
        raise ValueError("control characters and unpaired surrogates are not allowed")
    return value


Name = Annotated[str, Field(min_length=1, max_length=200), AfterValidator(_plain_text)]
DeviceModel = Annotated[
    str,
    Field(min_length=1, max_length=128, description="the phone's model name, plain text"),
    AfterValidator(_plain_text),
]


# a JSON array fills a tuple; its items keep their own strict types
LAX_ARRAY = StrictMode(False)


class Strict(BaseModel):
    """Every wire model: unknown fields refused."""

    model_config = ConfigDict(extra="forbid", ser_json_inf_nan="null")


class StrictIn(Strict):
    """What clients send: no coercion either (``"1"``, ``true`` or ``1.0`` is not an
    integer, ``"1"`` or ``true`` not a number; JSON arrays still fill tuples)."""

    model_config = ConfigDict(strict=True)
