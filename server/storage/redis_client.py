"""One Redis client for a configured URL: a single server (``redis://``, ``rediss://``,
``unix://``) or a Redis Cluster (``redis+cluster://host:port``, any node; the client
learns the others from it). Every key the stores use carries a hash tag or stands alone,
so each command and script touches one slot and runs unchanged on a cluster."""

from __future__ import annotations

from typing import cast

from redis.asyncio import Redis
from redis.asyncio.cluster import RedisCluster
from redis.commands.core import AsyncScript

CLUSTER_SCHEME = "redis+cluster://"
CONNECT_TIMEOUT_S = 5.0  # fail a ping fast when Redis is unreachable

AnyRedis = Redis | RedisCluster


def redis_client(
    url: str, *, decode_responses: bool = False, connect_timeout_s: float = CONNECT_TIMEOUT_S
) -> AnyRedis:
    """The client for ``url`` (module docstring)."""
    if url.startswith(CLUSTER_SCHEME):
        return RedisCluster.from_url(
            "redis://" + url.removeprefix(CLUSTER_SCHEME),
            decode_responses=decode_responses,
            socket_connect_timeout=connect_timeout_s,
        )
    client: Redis = Redis.from_url(
        url, decode_responses=decode_responses, socket_connect_timeout=connect_timeout_s
    )
    return client


def register_script(client: AnyRedis, lua: str) -> AsyncScript:
    """``client.register_script(lua)``: a cluster client runs it by EVALSHA on the node of
    the script's key, as one server would (redis-py types the method for ``Redis`` only)."""
    return cast(Redis, client).register_script(lua)
