"""What an upload may carry, and the walk read from it.

An ILC 2.0 path file (``text/plain``; the API decompresses ``application/x-xz`` first),
read strictly (``ilc_trace_format.parse_trace_text``): the first record that cannot be read is
refused with its line number, so the sender hears what is wrong. Or our own stored shape
(``trace_codec.CONTENT_TYPE``), which the API makes from validated events only.
"""

from __future__ import annotations

from server.positioning.model.walk import Walk
from server.services.errors import Invalid
from server.storage.codec import CodecError
from server.storage.ilc_trace_format import TraceFormatError, parse_trace_text
from server.storage.trace_codec import CONTENT_TYPE, decode_trace

ILC_TEXT = "text/plain"


def parse_payload(content_type: str, payload: bytes, path_id: str) -> Walk:
    """The trace an upload carries; :class:`Invalid` naming the line when it cannot be read."""
    if content_type == CONTENT_TYPE:
        try:
            return decode_trace(payload, path_id)
        except (CodecError, KeyError) as exc:
            raise Invalid(f"not a stored trace: {exc}", field="body") from None
    if content_type != ILC_TEXT:
        raise Invalid(
            f"unsupported content type {content_type!r}: send text/plain (ILC 2.0), "
            "application/x-xz or application/json (our events)",
            field="content-type",
        )
    try:
        text = payload.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise Invalid(f"byte {exc.start}: the trace is not UTF-8 text", field="body") from None
    try:
        trace = parse_trace_text(text, path_id)
    except TraceFormatError as exc:
        raise Invalid(f"line {exc.line}: {exc.reason}", field="body") from None
    if trace.t_last_ms == 0:
        raise Invalid("the trace holds no records", field="body")
    return trace
