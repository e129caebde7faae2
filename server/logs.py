"""Log output: one JSON object per line, or plain text, for the app and uvicorn alike.

``INDOORPOS_LOG_FORMAT=json`` writes lines such as::

    {"ts":"2024-05-01T12:00:00.123Z","level":"ERROR","logger":"server.api.live",
     "message":"batch over the live socket failed","session_id":"9f0c…","exc":"Traceback…"}

with ``session_id`` whenever the line was written while serving a session (the routes set
:data:`session_id_var` through :func:`session_context`), ``exc`` for an exception, and any
JSON-serialisable ``extra={...}`` fields of the call. ``text`` (the default) writes
``time level logger message`` lines, with ``session_id=…`` appended when one is set.

:func:`dict_config` is a ``logging.config.dictConfig`` document: the server hands it to
uvicorn, which applies it in every worker process; :func:`configure` applies it here.
"""

from __future__ import annotations

import logging
import logging.config
import re
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Any, Literal

import orjson

LogFormat = Literal["json", "text"]

session_id_var: ContextVar[str | None] = ContextVar("session_id", default=None)

# attributes every LogRecord has; anything else on a record came from ``extra=``
_RECORD_ATTRS = frozenset(logging.LogRecord("", 0, "", 0, "", None, None).__dict__) | {
    "message",
    "asctime",
    "taskName",  # Python 3.12+
    "color_message",  # uvicorn's coloured copy of the message
}
UVICORN_LOGGERS = ("uvicorn", "uvicorn.error", "uvicorn.access")


@contextmanager
def session_context(session_id: str) -> Iterator[None]:
    """Tag every log line written inside the block (and in tasks and worker threads it
    starts) with ``session_id``."""
    token = session_id_var.set(session_id)
    try:
        yield
    finally:
        session_id_var.reset(token)


# credentials as they show up in log lines: in a URL's query (``?token=``, as uvicorn logs
# request paths), in a header (``Authorization: Bearer ...``, as the websockets library
# logs a handshake at DEBUG) and in a JSON message (``"token": "..."``, a socket's frames)
_SECRETS = re.compile(
    r"""([?&](?:token|access_token|key|api_key)=)[^&\s"']*"""
    r"|(authorization:\s*[a-z]+\s+)[^\s\"']+"
    r"""|(["'](?:token|key|api_key)["']\s*:\s*["'])[^"']*""",
    re.IGNORECASE,
)


def redact(text: str) -> str:
    """``text`` with every credential :data:`_SECRETS` finds replaced by ``[redacted]``."""
    return _SECRETS.sub(lambda m: f"{m.group(1) or m.group(2) or m.group(3)}[redacted]", text)


class RedactSecrets(logging.Filter):
    """Replaces credentials (:func:`redact`) in every record's message (the arguments
    formatted in first), whatever logger wrote it."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        scrubbed = redact(message)
        if scrubbed != message:
            record.msg, record.args = scrubbed, ()
            record.__dict__.pop("color_message", None)
        return True


# an answered batch: a phone posts one a step, so its access line would be most of the log
# and a share of the server's time; the metrics count batches (indoorpos_batches_total)
_BATCH_PATH = re.compile(r"^/v1/sessions/[0-9a-f]{32}/batches$")


class QuietBatches(logging.Filter):
    """Lowers the access line of an answered batch (2xx) to DEBUG: written only when the
    log level is DEBUG. Other requests, and batches refused, keep their INFO line."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        # uvicorn's access record: (client, method, path, http version, status)
        if not (isinstance(args, tuple) and len(args) == 5 and args[1] == "POST"):
            return True
        status, path = args[4], str(args[2])
        if not (isinstance(status, int) and status < 300 and _BATCH_PATH.match(path)):
            return True
        record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return logging.getLogger().isEnabledFor(logging.DEBUG)


class JsonFormatter(logging.Formatter):
    """One JSON object per record: ``ts`` (ISO-8601, UTC), ``level``, ``logger``,
    ``message``, then ``session_id``, ``exc``, ``stack`` and the extra fields when present."""

    def format(self, record: logging.LogRecord) -> str:
        ts = datetime.fromtimestamp(record.created, tz=UTC)
        out: dict[str, Any] = {
            "ts": ts.isoformat(timespec="milliseconds").replace("+00:00", "Z"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        session_id = session_id_var.get()
        if session_id is not None:
            out["session_id"] = session_id
        if record.exc_info:
            out["exc"] = self.formatException(record.exc_info)
        elif record.exc_text:
            out["exc"] = record.exc_text
        if record.stack_info:
            out["stack"] = self.formatStack(record.stack_info)
        for key, value in record.__dict__.items():
            if key in _RECORD_ATTRS or key in out or key.startswith("_"):
                continue
            try:
                orjson.dumps(value)
            except TypeError:
                continue  # not JSON: left out rather than losing the line
            out[key] = value
        return orjson.dumps(out).decode()


class TextFormatter(logging.Formatter):
    """``time level logger message``, plus `` session_id=…`` when one is set."""

    def __init__(self) -> None:
        super().__init__("%(asctime)s %(levelname)s %(name)s %(message)s")

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 (logging's name)
        line = super().formatMessage(record)
        session_id = session_id_var.get()
        return line if session_id is None else f"{line} session_id={session_id}"


def dict_config(fmt: LogFormat, level: str) -> dict[str, Any]:
    """A ``dictConfig`` document: one stderr handler on the root logger with the chosen
    formatter and :class:`RedactSecrets`; uvicorn's loggers hand their records to it,
    the access log through :class:`QuietBatches`."""
    formatter = JsonFormatter if fmt == "json" else TextFormatter
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"indoorpos": {"()": f"{__name__}.{formatter.__name__}"}},
        "filters": {
            "redact": {"()": f"{__name__}.{RedactSecrets.__name__}"},
            "quiet_batches": {"()": f"{__name__}.{QuietBatches.__name__}"},
        },
        "handlers": {
            "indoorpos": {
                "class": "logging.StreamHandler",
                "formatter": "indoorpos",
                "filters": ["redact"],
                "stream": "ext://sys.stderr",
            }
        },
        "root": {"handlers": ["indoorpos"], "level": level.upper()},
        "loggers": {
            **{name: {"handlers": [], "propagate": True} for name in UVICORN_LOGGERS},
            "uvicorn.access": {"handlers": [], "propagate": True, "filters": ["quiet_batches"]},
        },
    }


def configure(fmt: LogFormat, level: str) -> None:
    """Send every log line of this process through the chosen formatter, at ``level``."""
    logging.config.dictConfig(dict_config(fmt, level))
