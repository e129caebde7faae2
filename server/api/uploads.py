"""Crowdsourced uploads: a trace in, 202 and an id out; its status and report later.

The body is an ILC 2.0 path file (``text/plain``), optionally xz-compressed
(``Content-Encoding: xz`` or ``Content-Type: application/x-xz``), or a walk as our own
events with its anchors (``application/json``, ``UploadTraceIn``); the site, building,
floor hint and device model come as query parameters. An ``Idempotency-Key`` header makes
a retried upload return the first one instead of creating another.
"""

from __future__ import annotations

import logging
import lzma
from typing import Annotated, Any

import anyio
from fastapi import APIRouter, Header, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError
from pydantic.json_schema import models_json_schema
from starlette.requests import ClientDisconnect

from server.api.convert import to_events
from server.api.deps import (
    IdPath,
    MapsWriter,
    PageQuery,
    RuntimeDep,
    SqlDep,
    Viewer,
    client_address,
    page_query,
)
from server.api.gated_route import GatedRoute
from server.api.schemas.common import ID_PATTERN, DeviceModel
from server.api.schemas.pages import CREATED, encode_cursor
from server.api.schemas.uploads import UploadList, UploadRead, UploadStatus, UploadTraceIn
from server.positioning.model.walk import trace_from_events
from server.services import limits, uploads
from server.services.errors import Invalid, TooLarge, not_found
from server.services.upload_payloads import ILC_TEXT
from server.storage import trace_codec

router = APIRouter(prefix="/v1", tags=["uploads"], route_class=GatedRoute)
log = logging.getLogger("indoorpos.api.uploads")

XZ_TYPES = {"application/x-xz", "application/xz"}
UploadPage = Annotated[PageQuery, page_query("uploads", CREATED)]


async def _body(request: Request, limit: int) -> bytes:
    """The request body, refused with 413 past ``limit`` bytes (before reading it all)."""
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise TooLarge(f"the body is {declared} bytes; at most {limit}", field="body")
    chunks, total = [], 0
    try:
        async for chunk in request.stream():
            total += len(chunk)
            if total > limit:
                raise TooLarge(f"the body is over {limit} bytes", field="body")
            chunks.append(chunk)
    except ClientDisconnect:  # gone, or cut off by the body limit (which answered 413)
        raise TooLarge(
            f"the body is over {limit} bytes, or was not sent whole", field="body"
        ) from None
    return b"".join(chunks)


def _decompress(data: bytes, limit: int) -> bytes:
    decompressor = lzma.LZMADecompressor(format=lzma.FORMAT_XZ)
    try:
        out = decompressor.decompress(data, max_length=limit + 1)
    except lzma.LZMAError as exc:
        raise Invalid(f"the body is not xz data: {exc}", field="body") from None
    if len(out) > limit:
        raise TooLarge(f"the trace is over {limit} bytes once decompressed", field="body")
    if not decompressor.eof:
        raise Invalid("the xz data ends early", field="body")
    return out


def _events_trace(payload: bytes) -> bytes:
    """A JSON walk (``UploadTraceIn``), validated (422 naming the field) and stored in the
    shape the map builder reads (``storage.trace_codec``)."""
    try:
        walk = UploadTraceIn.model_validate_json(payload)
    except ValidationError as exc:
        raise RequestValidationError(exc.errors()) from None
    anchors = [(a.t, a.x_m, a.y_m) for a in walk.anchors]
    return trace_codec.encode_trace(trace_from_events(to_events(walk.events), anchors))


@router.post(
    "/uploads",
    status_code=status.HTTP_202_ACCEPTED,
    responses={200: {"model": UploadRead, "description": "a retry of an earlier upload"}},
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "text/plain": {"schema": {"type": "string"}},
                "application/x-xz": {"schema": {"type": "string", "format": "binary"}},
                "application/json": {"schema": {"$ref": "#/components/schemas/UploadTraceIn"}},
            },
        }
    },
)
async def create_upload(
    request: Request,
    response: Response,
    rt: RuntimeDep,
    site_id: Annotated[str, Query(pattern=ID_PATTERN)],
    building_id: Annotated[str | None, Query(pattern=ID_PATTERN)] = None,
    floor: Annotated[int | None, Query(ge=-20, le=200, description="floor level hint")] = None,
    device_model: Annotated[DeviceModel | None, Query()] = None,
    content_type: Annotated[str, Header()] = "text/plain",
    content_encoding: Annotated[str | None, Header()] = None,
    idempotency_key: Annotated[str | None, Header(min_length=1, max_length=128)] = None,
    *,
    principal: MapsWriter,
) -> UploadRead:
    """Accept a trace for the map builder (202); the worker folds it in later."""
    principal.require("maps:write", site_id)
    await limits.check(rt, "uploads", client_address(request), principal.key_id)
    limit = rt.settings.upload_max_bytes
    media = content_type.split(";", 1)[0].strip().lower()
    if media == trace_codec.CONTENT_TYPE:  # our stored shape: made here from validated input only
        raise Invalid(
            f"{media} is internal: send application/json, text/plain or application/x-xz",
            field="content-type",
        )
    payload = await _body(request, limit)
    if media in XZ_TYPES or (content_encoding or "").strip().lower() == "xz":
        payload = await anyio.to_thread.run_sync(_decompress, payload, limit)
        media = ILC_TEXT if media in XZ_TYPES else media
    if media == "application/json":
        payload = await anyio.to_thread.run_sync(_events_trace, payload)
        media = trace_codec.CONTENT_TYPE
    new = uploads.NewUpload(
        site_id=site_id,
        building_id=building_id,
        floor_level=floor,
        device_model=device_model,
        content_type=media,
        payload=payload,
        idempotency_key=idempotency_key,
    )
    async with rt.transaction() as s:
        row, created = await uploads.create_upload(s, new)
        out = _read(row)
    # committed: from here the upload cannot be lost; a failed publish is recovered by the
    # worker's scan for stranded uploads
    if created:
        try:
            await rt.uploads.publish(out.id)
        except Exception:
            log.exception("upload %s stored but not queued; the worker will find it", out.id)
    else:
        response.status_code = status.HTTP_200_OK
    return out


@router.get("/uploads")
async def list_uploads(
    s: SqlDep,
    principal: Viewer,
    page: UploadPage,
    site_id: Annotated[str | None, Query(pattern=ID_PATTERN, description="one site's only")] = None,
    upload_status: Annotated[
        UploadStatus | None, Query(alias="status", description="in this status only")
    ] = None,
) -> UploadList:
    """Uploads newest first, with their status and report (a key of one site sees that
    site's)."""
    if site_id is not None and not principal.sees(site_id):
        # another site's uploads are as invisible as a site that does not exist
        return UploadList(items=[], count=0, next_cursor=None)
    site_id = site_id or principal.site_id
    found = await uploads.list_uploads(s, site_id, upload_status, page.after, page.limit)
    items = [_read(row) for row in found.rows]
    cursor = encode_cursor("uploads", found.next_key) if found.next_key is not None else None
    return UploadList(items=items, count=len(items), next_cursor=cursor)


@router.get("/uploads/{upload_id}")
async def get_upload(upload_id: IdPath, s: SqlDep, principal: Viewer) -> UploadRead:
    row = await uploads.get_upload(s, upload_id)
    principal.require("viewer", row.site_id, missing=not_found("upload", upload_id))
    return _read(row)


def _read(row: Any) -> UploadRead:
    return UploadRead(
        id=row.id,
        site_id=row.site_id,
        building_id=row.building_id,
        floor=row.floor_level,
        device_model=row.device_model,
        status=row.status,
        attempts=row.attempts,
        report=row.report,
        created_at=row.created_at,
        updated_at=row.updated_at,
    )


def openapi_schemas() -> dict[str, Any]:
    """Schemas of bodies this router reads by hand (the JSON walk), for the OpenAPI
    document's components: FastAPI lists only models it validates itself."""
    _, top = models_json_schema(
        [(UploadTraceIn, "validation")], ref_template="#/components/schemas/{model}"
    )
    schemas: dict[str, Any] = top.get("$defs", {})
    return schemas
