"""Schemathesis against the served app, from its own OpenAPI document: with an admin key, a
device key, a viewer key of one site and no key, no answer is a 5xx and every answer is
one the document lists, in its shape. The batch route also gets bodies the schema allows,
on a live session."""

from __future__ import annotations

import asyncio
import itertools
import logging
import os
import re
from collections import Counter
from typing import Any

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.checks import (
    content_type_conformance,
    not_a_server_error,
    response_schema_conformance,
    status_code_conformance,
)

from tests.support.admin_key import ADMIN_KEY
from tests.support.toy_site import ToySite, build_toy_site

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
]
EXAMPLES_PER_OPERATION = 25  # per generation mode
MIN_REQUESTS_PER_CREDENTIAL = 1000
ADMIN = {"Authorization": f"Bearer {ADMIN_KEY}"}
log = logging.getLogger(__name__)
# about three minutes: once per suite run, in its production-shape pass (PostgreSQL +
# Redis), which the README's test command and CI always make
pytestmark = pytest.mark.skipif(
    not os.environ.get("INDOORPOS_REDIS_URL"),
    reason="runs in the pass on PostgreSQL + Redis (INDOORPOS_REDIS_URL)",
)


@pytest.fixture(scope="module")
def toy(live_url: str) -> ToySite:
    async def build() -> ToySite:
        async with httpx.AsyncClient(base_url=live_url, timeout=30) as client:
            return await build_toy_site(client, ADMIN)

    return asyncio.run(build())


@pytest.fixture(scope="module")
def api_schema(live_url: str) -> Any:
    return schemathesis.openapi.from_url(f"{live_url}/openapi.json")


# a request with these is not HTTP at all: the HTTP server (uvicorn) refuses it with a
# plain-text 400 before the app sees it, so such cases test uvicorn, not the app
FRAMING_HEADERS = frozenset({"content-length", "transfer-encoding", "host", "connection"})
HEADER_NAME = re.compile(r"^[!#$%&'*+.^_`|~0-9A-Za-z-]+$")  # RFC 9110 token
HEADER_VALUE = re.compile(r"^[\t\x20-\x7e\x80-\xff]*$")  # visible characters, no CR/LF


def _http_headers(generated: dict[str, Any] | None) -> dict[str, Any] | None:
    """The generated headers a well-formed HTTP request can carry: framing headers, names
    that are not HTTP tokens and values with control characters are left out."""
    if not generated:
        return generated
    return {
        name: value
        for name, value in generated.items()
        if name.lower() not in FRAMING_HEADERS
        and HEADER_NAME.match(name)
        and HEADER_VALUE.match(str(value))
    }


def _fuzz(api_schema: Any, live_url: str, headers: dict[str, str]) -> Counter[int]:
    """Every operation with ``EXAMPLES_PER_OPERATION`` generated requests per generation
    mode; the failures of all operations are reported together. Returns how many answers
    of each status came back."""
    statuses: Counter[int] = Counter()
    failures: list[str] = []
    operations = [result.ok() for result in api_schema.get_all_operations()]
    for operation, mode in itertools.product(operations, GenerationMode):
        # positive: what the document allows; negative: what it does not (must be a 4xx)

        @given(case=operation.as_strategy(mode))
        @settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            database=None,
        )
        def call(case: Any) -> None:
            case.headers = _http_headers(case.headers)
            response = case.call_and_validate(base_url=live_url, headers=headers, checks=CHECKS)
            statuses[response.status_code] += 1

        try:
            call()
        except Unsatisfiable:  # nothing to make invalid (a route without inputs)
            assert mode is GenerationMode.NEGATIVE
        except Exception as exc:  # one operation's failure must not hide the others'
            failures.append(f"{operation.label} ({mode.value}): {exc}")
    assert not failures, "\n\n".join(failures)
    return statuses


@pytest.mark.slow
@pytest.mark.parametrize("credential", ["admin", "device", "viewer", "none"])
def test_nothing_answers_5xx_or_off_its_schema(
    api_schema: Any, live_url: str, toy: ToySite, credential: str
) -> None:
    headers = {"admin": ADMIN, "device": toy.device, "none": {}}.get(credential)
    if headers is None:
        body = {"name": "fuzz viewer", "scopes": ["viewer"], "site_id": toy.site_id}
        r = httpx.post(f"{live_url}/v1/keys", json=body, headers=ADMIN)
        assert r.status_code == 201, r.text
        headers = {"Authorization": f"Bearer {r.json()['key']}"}
    statuses = _fuzz(api_schema, live_url, headers)
    log.info("%s: %d requests, statuses %s", credential, statuses.total(), sorted(statuses.items()))
    assert sum(statuses.values()) >= MIN_REQUESTS_PER_CREDENTIAL, statuses


@pytest.mark.slow
def test_batches_the_schema_allows_never_fail_a_live_session(
    api_schema: Any, live_url: str, toy: ToySite
) -> None:
    operation = api_schema["/v1/sessions/{session_id}/batches"]["POST"]
    seen: Counter[int] = Counter()

    @given(case=operation.as_strategy())
    @settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
    def post(case: Any) -> None:
        r = httpx.post(f"{live_url}/v1/sessions", json={"site_id": toy.site_id}, headers=toy.device)
        assert r.status_code == 201, r.text
        session = r.json()
        case.path_parameters = {"session_id": session["id"]}
        if isinstance(case.body, dict):
            case.body["seq"] = 1
        response = case.call_and_validate(
            base_url=live_url,
            headers={"Authorization": f"Bearer {session['token']}"},
            checks=CHECKS,
        )
        seen[response.status_code] += 1

    post()
    assert seen[200] > 0, seen  # valid batches were applied, not only refused
    assert set(seen) <= {200, 409, 422}, seen
