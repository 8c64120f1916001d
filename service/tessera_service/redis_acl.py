"""The Redis users of a farm: one for the API, one for the workers, each allowed only the
commands and keys it needs; the `default` user is off, so a connection without a password
can do nothing. Used by the embedded Redis (embedded.redis_server) and written out as
deploy/users.acl (tests/farm/test_redis_acl.py checks that the two agree).

Commands: the data-type and scripting commands the farm uses, without anything Redis
calls dangerous or admin (FLUSHALL, FLUSHDB, CONFIG, KEYS, DEBUG, SHUTDOWN, MONITOR, ACL,
MODULE, REPLICAOF, CLIENT KILL, INFO ...), without functions (FUNCTION LOAD would store
code) and without the key-listing commands (SCAN, RANDOMKEY), which ignore key patterns.
The API may also run ACL DRYRUN (it asks nothing about passwords), to check at start-up
that the default user lets Redis replay its append-only file (aof_replay_problem).

The default user: off (no connection can use it: NOAUTH) but allowed every command, key
and channel. Redis 7.0 (Debian 12's 7.0.15; fixed in Redis only in late 2025,
redis/redis#14545) replays the append-only file as the default user and re-checks ACLs at
every EXEC, so with `user default off -@all` each MULTI/EXEC and every Lua script's effects
(replicated as MULTI/EXEC) were refused with -NOPERM at load: a restart of Redis lost every
job. The rights of a user that is off cannot be used by a client.

Keys: the API reaches everything under the `tessera:` prefix. A worker reaches the scenes
(it stores the translated blob in the scene's hash, once for every worker, and the job that
ends last starts its scene's retention), the jobs and the workers, but never pre-flight
results, the job index or the per-user indexes: a compromised render host cannot mark a
hostile scene as inspected nor list other users' jobs. (It could alter a stored scene, as
it could alter the tiles it renders: workers are trusted with the images they make.) A new
family of keys that workers write must be added here.
"""
from __future__ import annotations

import logging
import re
import secrets
from dataclasses import dataclass
from urllib.parse import urlsplit, urlunsplit

import redis

from tessera_queue import redis_schema as rdb

log = logging.getLogger("tessera.service")

API_USER = "tessera-api"
WORKER_USER = "tessera-worker"

COMMANDS = ("-@all +@read +@write +@keyspace +@hash +@list +@set +@sortedset +@stream "
            "+@string +@transaction +@connection +@blocking +@scripting "
            "-@dangerous -@admin -function -fcall -fcall_ro -script|flush -script|kill "
            "-script|debug -scan -randomkey -swapdb -move")

# What the API user may run beyond COMMANDS: ACL DRYRUN, for aof_replay_problem.
API_EXTRA = "+acl|dryrun"
DEFAULT_RULE = "user default off ~* &* +@all"

API_KEYS = (f"~{rdb.PREFIX}:*",)
WORKER_KEYS = (
    f"~{rdb.scene_key('*')}",  # the scene hash and its scene_jobs set
    f"~{rdb.job_key('*')}",    # the job hash and every per-job key under it
    f"~{rdb.worker_key('*')}",
    f"~{rdb.data_key('*')}",   # the data store's index (translated scenes) and its store id
    *(f"~{key}" for key in (rdb.READY, rdb.ACTIVE, rdb.WORKERS, rdb.STATS, rdb.WAKE,
                            rdb.DEAD_LETTER)),
)


def user_rule(name: str, password: str) -> str:
    """One `user ...` line of an ACL file (redis.conf's aclfile)."""
    keys = API_KEYS if name == API_USER else WORKER_KEYS
    extra = (API_EXTRA,) if name == API_USER else ()
    return " ".join(("user", name, "on", f">{password}", "resetkeys", *keys,
                     "resetchannels", COMMANDS, *extra))


def acl_file(api_password: str, worker_password: str) -> str:
    return "\n".join((DEFAULT_RULE,
                      user_rule(API_USER, api_password),
                      user_rule(WORKER_USER, worker_password))) + "\n"


# Commands the farm runs inside MULTI/EXEC or Lua scripts (whose effects Redis 7 writes to
# the append-only file as MULTI/EXEC): the default user must be allowed each of them on the
# farm's keys for the file to replay. A sample of the writes, not every argument form.
REPLAYED = (("MULTI",), ("EXEC",), ("HSET", "K", "f", "v"), ("HSETNX", "K", "f", "v"),
            ("HINCRBY", "K", "f", "1"), ("HINCRBYFLOAT", "K", "f", "1"), ("HDEL", "K", "f"),
            ("SET", "K", "v"), ("DEL", "K"), ("EXPIRE", "K", "1"), ("PEXPIRE", "K", "1"),
            ("PERSIST", "K"), ("SADD", "K", "m"), ("SREM", "K", "m"), ("ZADD", "K", "1", "m"),
            ("ZREM", "K", "m"), ("ZINCRBY", "K", "1", "m"), ("RPUSH", "K", "v"),
            ("LTRIM", "K", "0", "1"), ("XADD", "K", "*", "f", "v"), ("XACK", "K", "g", "0-1"),
            ("XDEL", "K", "0-1"), ("XCLAIM", "K", "g", "c", "0", "0-1"),
            ("XGROUP", "CREATE", "K", "g", "$", "MKSTREAM"))


def redis_version(client) -> tuple[int, ...]:
    """The server's version, from HELLO (every authenticated user may run it; INFO is an
    admin command)."""
    reply = client.execute_command("HELLO")
    if isinstance(reply, (list, tuple)):  # RESP2: a flat list of names and values
        reply = dict(zip(reply[0::2], reply[1::2]))
    version = {(k.decode() if isinstance(k, bytes) else k): v for k, v in reply.items()}["version"]
    version = version.decode() if isinstance(version, bytes) else version
    return tuple(int(part) for part in re.findall(r"\d+", version)[:3])


def aof_replay_problem(client) -> str | None:
    """Why this Redis would drop accepted jobs when it replays its append-only file after
    a restart (see the module docstring), or None when it would not or cannot tell. Asks
    ACL DRYRUN whether the default user may run what the farm's transactions run; a user
    that may not run ACL DRYRUN (an ACL older than deploy/users.acl) gets a warning
    instead (logged here), since the rules cannot be read."""
    try:
        version = redis_version(client)
    except redis.ResponseError:  # no HELLO: Redis 5 or older, long before the re-check
        return None
    if version < (7, 0):  # no EXEC re-check at load before 7.0 (and no ACL DRYRUN)
        return None
    key = f"{rdb.PREFIX}:aof-replay-check"
    refused = []
    try:
        for command in REPLAYED:
            args = [key if a == "K" else a for a in command]
            answer = client.execute_command("ACL", "DRYRUN", "default", *args)
            if answer not in (b"OK", "OK"):
                refused.append(command[0] if command[0] != "XGROUP" else "XGROUP CREATE")
    except redis.exceptions.NoPermissionError:
        log.warning("cannot check that Redis %s will replay its append-only file after a "
                    "restart: this Redis user may not run ACL DRYRUN (grant +acl|dryrun as "
                    "deploy/users.acl does). Make sure the default user is `user default off "
                    "~* &* +@all`, or a restart of Redis loses every job (docs/farm.md, "
                    "\"Redis restarts\")", ".".join(map(str, version)))
        return None
    if not refused:
        return None
    return (f"Redis {'.'.join(map(str, version))} replays its append-only file as the "
            f"default user, which may not run {', '.join(refused)} on the farm's keys: after a "
            f"restart it would refuse every transaction in the file and lose the jobs. Give "
            f"the default user every right while keeping it off (`{DEFAULT_RULE}` in the ACL "
            f"file, as deploy/users.acl; it stays unusable without a password) and restart "
            f"Redis (docs/farm.md, \"Redis restarts\")")


@dataclass(frozen=True)
class Credentials:
    api_password: str
    worker_password: str

    @classmethod
    def generate(cls) -> "Credentials":
        return cls(secrets.token_urlsafe(32), secrets.token_urlsafe(32))

    def url(self, user: str, host: str, port: int, db: int = 0) -> str:
        password = self.api_password if user == API_USER else self.worker_password
        return f"redis://{user}:{password}@{host}:{port}/{db}"


def redacted(url: str) -> str:
    """The URL without its password, for logs."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = f"{parts.username or ''}:***@{parts.hostname}" + (f":{parts.port}" if parts.port else "")
    return urlunsplit(parts._replace(netloc=netloc))
