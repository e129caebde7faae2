"""Rate limits per key, per client address and per session (``Settings.rate_*``), on the
buckets of ``storage.rate_limits`` shared by every replica.

Each call names its action and the subjects it is counted against; the first subject
whose bucket is empty refuses the call with ``TooMany`` (429 with ``Retry-After``). A
bucket holds a minute's worth of calls and refills evenly over the minute.
"""

from __future__ import annotations

from server.services.errors import TooMany
from server.services.runtime import Runtime
from server.storage.rate_limits import retry_after_s
from server.storage.session_store import Allowance

# per-key (and per-address, for batches) allowance as a multiple of the base setting: a
# device key is shared by every phone of an app, an address by the phones behind a NAT
KEY_FACTOR = 100
ADDRESS_FACTOR_BATCHES = 10


async def _take(rt: Runtime, action: str, subject: str, per_min: int) -> None:
    wait = await rt.limits.take(f"{action}:{subject}", per_min / 60.0, per_min)
    if wait is not None:
        raise too_many(action, subject.split(":", 1)[0], wait)


def too_many(action: str, subject: str, wait_s: float) -> TooMany:
    """The refusal of an ``action`` call past the allowance of its ``subject`` (address,
    key, session)."""
    return TooMany(
        f"too many {action} calls for this {subject}; retry later",
        retry_after_s(wait_s),
        field="request",
    )


async def check(rt: Runtime, action: str, address: str, key: str | None = None) -> None:
    """Count a ``sessions``, ``locate`` or ``uploads`` call against the client address
    and the key (its id; None for the configured admin key, which is not limited)."""
    if not rt.settings.rate_limits:
        return
    base = {
        "sessions": rt.settings.rate_sessions_per_min,
        "locate": rt.settings.rate_locate_per_min,
        "uploads": rt.settings.rate_uploads_per_min,
    }[action]
    await _take(rt, action, f"address:{address}", base)
    if key is not None:
        factor = 1 if action == "uploads" else KEY_FACTOR
        await _take(rt, action, f"key:{key}", base * factor)


def check_batch(rt: Runtime, session_id: str, address: str) -> None:
    """Refuse a batch of a session whose bucket this process last found empty, and count
    a batch against its client address (no I/O: ``RateLimiter.spend``)."""
    if not rt.settings.rate_limits:
        return
    wait = rt.limits.empty.wait(f"batches:session:{session_id}")
    if wait is not None:
        raise too_many("batches", "session", wait)
    per_min = rt.settings.rate_batches_per_min * ADDRESS_FACTOR_BATCHES
    wait = rt.limits.spend(f"batches:address:{address}", per_min / 60.0, per_min)
    if wait is not None:
        raise too_many("batches", "address", wait)


def session_bucket_empty(rt: Runtime, session_id: str, wait_s: float) -> TooMany:
    """The refusal of a batch its session's bucket had no token for (the write said so),
    remembered here until a token is back."""
    rt.limits.empty.note(f"batches:session:{session_id}", wait_s)
    return too_many("batches", "session", wait_s)


def batch_allowance(rt: Runtime) -> Allowance | None:
    """The allowance of a session's own bucket, taken by the write that applies a batch
    (None with rate limits off)."""
    if not rt.settings.rate_limits:
        return None
    per_min = rt.settings.rate_batches_per_min
    return Allowance(per_min / 60.0, per_min)


async def check_auth_failure(rt: Runtime, address: str) -> None:
    """Count a failed authentication; TooMany once the address has failed too often."""
    if not rt.settings.rate_limits:
        return
    await _take(rt, "authentication", f"address:{address}", rt.settings.rate_auth_failures_per_min)


async def refuse_failing_address(rt: Runtime, address: str) -> None:
    """TooMany, before any credential is looked at, for an address that has failed to
    authenticate too often of late (its right key too waits out the penalty)."""
    if not rt.settings.rate_limits:
        return
    per_min = rt.settings.rate_auth_failures_per_min
    wait = await rt.limits.peek(f"authentication:address:{address}", per_min / 60.0, per_min)
    if wait is not None:
        raise TooMany(
            "too many failed authentications from this address; retry later",
            retry_after_s(wait),
            field="request",
        )
