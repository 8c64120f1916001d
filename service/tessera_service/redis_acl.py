"""The Redis users of a farm: one for the API, one for the workers, each allowed only the
commands and keys it needs; the `default` user is off, so a connection without a password
can do nothing. Used by the embedded Redis (embedded.redis_server) and written out as
deploy/users.acl (tests/farm/test_redis_acl.py checks that the two agree).

Commands: the data-type and scripting commands the farm uses, without anything Redis
calls dangerous or admin (FLUSHALL, FLUSHDB, CONFIG, KEYS, DEBUG, SHUTDOWN, MONITOR, ACL,
MODULE, REPLICAOF, CLIENT KILL, INFO ...), without functions (FUNCTION LOAD would store
code) and without the key-listing commands (SCAN, RANDOMKEY), which ignore key patterns.

Keys: the API reaches everything under the `tessera:` prefix. A worker reaches the scenes
(it stores the translated blob in the scene's hash, once for every worker, and the job that
ends last starts its scene's retention), the jobs and the workers, but never pre-flight
results, the job index or the per-user indexes: a compromised render host cannot mark a
hostile scene as inspected nor list other users' jobs. (It could alter a stored scene, as
it could alter the tiles it renders: workers are trusted with the images they make.) A new
family of keys that workers write must be added here.
"""
from __future__ import annotations

import secrets
from dataclasses import dataclass
from urllib.parse import urlsplit, urlunsplit

from tessera_queue import redis_schema as rdb

API_USER = "tessera-api"
WORKER_USER = "tessera-worker"

COMMANDS = ("-@all +@read +@write +@keyspace +@hash +@list +@set +@sortedset +@stream "
            "+@string +@transaction +@connection +@blocking +@scripting "
            "-@dangerous -@admin -function -fcall -fcall_ro -script|flush -script|kill "
            "-script|debug -scan -randomkey -swapdb -move")

API_KEYS = (f"~{rdb.PREFIX}:*",)
WORKER_KEYS = (
    f"~{rdb.scene_key('*')}",  # the scene hash and its scene_jobs set
    f"~{rdb.job_key('*')}",    # the job hash and every per-job key under it
    f"~{rdb.worker_key('*')}",
    *(f"~{key}" for key in (rdb.READY, rdb.ACTIVE, rdb.WORKERS, rdb.STATS, rdb.WAKE,
                            rdb.DEAD_LETTER)),
)


def user_rule(name: str, password: str) -> str:
    """One `user ...` line of an ACL file (redis.conf's aclfile)."""
    keys = API_KEYS if name == API_USER else WORKER_KEYS
    return " ".join(("user", name, "on", f">{password}", "resetkeys", *keys,
                     "resetchannels", COMMANDS))


def acl_file(api_password: str, worker_password: str) -> str:
    return "\n".join(("user default off resetkeys resetchannels -@all",
                      user_rule(API_USER, api_password),
                      user_rule(WORKER_USER, worker_password))) + "\n"


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
