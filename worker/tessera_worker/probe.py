"""python -m tessera_worker.probe: a container health check for the worker on this host.

Exits 0 when a worker on this host (the heartbeat's `host` field, the container's
hostname) has a current heartbeat in Redis, 1 when none has: the worker died, never
registered, or cannot write to Redis with its credentials. When Redis itself cannot be
reached it exits 0: restarting the worker would not bring Redis back, and the worker
waits for it on its own. Reads REDIS_URL (or TESSERA_WORKER_REDIS_URL) like the worker."""
from __future__ import annotations

import socket
import sys

import redis

from tessera_queue import redis_schema as rdb

from .settings import WorkerSettings


def live_workers_on(client: redis.Redis, host: str) -> list[str]:
    names = [n.decode() for n in client.smembers(rdb.WORKERS)]
    with client.pipeline(transaction=False) as pipe:
        for name in names:
            pipe.hget(rdb.worker_key(name), "host")
        hosts = pipe.execute()
    return [n for n, h in zip(names, hosts) if h is not None and h.decode() == host]


def main() -> int:
    url = WorkerSettings().redis_url
    host = socket.gethostname()
    client = redis.Redis.from_url(url, socket_connect_timeout=3, socket_timeout=5)
    try:
        live = live_workers_on(client, host)
    except (redis.ConnectionError, redis.TimeoutError) as e:
        print(f"cannot reach redis ({e}); not the worker's fault, so reported healthy")
        return 0
    except redis.RedisError as e:
        print(f"redis refused the probe: {e}")
        return 1
    finally:
        client.close()
    if not live:
        print(f"no worker on {host} has a current heartbeat")
        return 1
    print(f"alive: {', '.join(sorted(live))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
