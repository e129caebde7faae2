"""What the service's commands print: the console, a masked database URL, a failure."""

from __future__ import annotations

import re
from typing import NoReturn

import typer
from rich.console import Console

console = Console()
_PASSWORD_PARAM = re.compile(r"([?&]password=)[^&]*", re.IGNORECASE)
_MASK = r"\1***"


def masked_url(url: str) -> str:
    """``url`` with its password, in the user part or a ``password=`` query parameter,
    replaced by ``***`` (for showing an operator which database a command used)."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        return url
    end = min((i for i in (rest.find("/"), rest.find("?")) if i >= 0), default=len(rest))
    authority, tail = rest[:end], rest[end:]
    userinfo, at, hostport = authority.rpartition("@")
    if at and ":" in userinfo:
        authority = f"{userinfo.split(':', 1)[0]}:***@{hostport}"
    return f"{scheme}://{authority}{_PASSWORD_PARAM.sub(_MASK, tail)}"


def fail(message: str) -> NoReturn:
    """One line on stderr (never wrapped, no traceback) and exit status 1."""
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(1)
