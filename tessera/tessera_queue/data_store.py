"""The farm's large bytes, out of the queue's Redis: uploaded files (PUT /blobs), the scenes
jobs render, and the renderer's translated scenes live as files named by their SHA-256 in
a data directory (TESSERA_DATA_DIR) that the API and every worker share; Redis keeps only
their index (size, holders). The service and the workers both go through this module, as
they go through redis_schema for keys.

Why a directory and not Redis: Redis holds everything in memory under the farm's
maxmemory, so six 250 MiB uploads filled it and POST /jobs answered 503 for everyone, and
one translated 10^7-triangle scene took 520 MB of it for a week. Files cost disk, not the
queue's memory. Why not an object store: the farm needs nothing an object store adds on
one machine, and a shared volume (NFS, a Kubernetes ReadWriteMany claim) serves several;
an S3 backend would be another implementation of this module's few operations.

Layout: DATA_DIR/<store id>/objects/<first 2 hex>/<sha256>, written as temporary files in
DATA_DIR/<store id>/tmp and renamed into place (a reader never sees part of an object),
and verified against their name whenever they are read. The store id is kept in Redis
(redis_schema.DATA_STORE_ID): one data directory may serve several farms (the tests'
Redis servers; a new, empty Redis), each under its own id, and a sweep never takes another
farm's objects for garbage.

Holders: an object is kept while one of its holders, Redis keys named in
redis_schema.data_holders_key, exists: the blob index (`blob_key`, which expires with the
upload's retention or is deleted with DELETE /blobs), or the scene hash (`scene_key`, for
the scene's bytes and its translated scenes; it does not expire while a job holds it and
expires the scene retention after the last one ended). `sweep` deletes the objects none
of whose holders exists, file and index.

Order, so that a sweep never deletes an object someone is storing: a writer records the
holder (index first), then writes the file if it is missing; an eviction deletes the index
(in a transaction that fails if a holder was added meanwhile), renames the file aside, and
deletes it only if no writer has recorded the object again since, else puts it back.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import re
import shutil
import time
import uuid
from pathlib import Path

import redis

from tessera_queue import redis_schema as rdb

DATA_DIR_ENV = "TESSERA_DATA_DIR"
_DIGEST = re.compile(rb"[0-9a-f]{64}")
TMP_MAX_AGE = 3600.0   # seconds: a temporary file this old was left by a killed writer
_CHUNK = 1 << 20


class ObjectMissing(RuntimeError):
    """An object the index names is not in the data directory (another directory than the
    API's, or lost), or its bytes do not match its name."""


def is_digest(value: bytes | None) -> bool:
    """Whether a Redis value names an object (a SHA-256 in hex), rather than holding the
    bytes themselves as farms before the data store did."""
    return value is not None and _DIGEST.fullmatch(value) is not None


def default_root() -> Path:
    """TESSERA_DATA_DIR, else the user's data folder (XDG_DATA_HOME/tessera/data): one
    machine's API and workers find each other's files there without a setting."""
    if os.environ.get(DATA_DIR_ENV):
        return Path(os.environ[DATA_DIR_ENV])
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base, "tessera", "data")


class DataStore:
    def __init__(self, root: str | os.PathLike, client: redis.Redis):
        self.root = Path(root)
        self.redis = client

    # ------------------------------------------------------------------ places
    def unusable(self) -> str | None:
        """Why this process cannot write to the data directory (a message for the log), or
        None."""
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            probe = self.root / f".probe.{os.getpid()}.{uuid.uuid4().hex[:8]}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            return (f"cannot write to the data directory {self.root} ({DATA_DIR_ENV}): {exc}; "
                    f"give it a writable folder that every worker shares")
        return None

    def store_dir(self) -> Path:
        """This farm's folder (see the module docstring), created when first needed. Read
        from Redis each time: a farm whose Redis starts empty is another farm."""
        sid = self.redis.get(rdb.DATA_STORE_ID)
        if sid is None:
            self.redis.set(rdb.DATA_STORE_ID, uuid.uuid4().hex, nx=True)
            sid = self.redis.get(rdb.DATA_STORE_ID)
        path = self.root / sid.decode()
        if not (path / "tmp").is_dir():
            (path / "objects").mkdir(parents=True, exist_ok=True)
            (path / "tmp").mkdir(exist_ok=True)
        return path

    def path(self, digest: str, base: Path | None = None) -> Path:
        return (base or self.store_dir()) / "objects" / digest[:2] / digest

    # ------------------------------------------------------------------ writing
    def hold(self, pipe, digest: str, size: int, holder: str) -> None:
        """Queues on `pipe` (a transaction that also creates or renews `holder`) the
        index of the object and `holder` among its holders. Then call write_* to make sure
        the file exists."""
        pipe.hset(rdb.data_key(digest), mapping={"size": size})
        pipe.sadd(rdb.data_holders_key(digest), holder)
        pipe.sadd(rdb.DATA_OBJECTS, digest)

    def write_file(self, digest: str, src: str | os.PathLike) -> Path:
        """Copies `src` (whose SHA-256 the caller has checked) in as object `digest`
        unless it is there already."""
        target = self.path(digest)
        if target.exists():
            return target
        return self._install(target, lambda out: _copy(src, out))

    def write_bytes(self, digest: str, data: bytes) -> Path:
        target = self.path(digest)
        if target.exists():
            return target
        return self._install(target, lambda out: out.write(data))

    def _install(self, target: Path, fill) -> Path:
        tmp = target.parent.parent.parent / "tmp" / f"{target.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
        try:
            with open(tmp, "wb") as out:
                fill(out)
                out.flush()
                os.fsync(out.fileno())
            target.parent.mkdir(exist_ok=True)
            os.replace(tmp, target)
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
        return target

    # ------------------------------------------------------------------ reading
    def read_bytes(self, digest: str) -> bytes:
        """The object's bytes, checked against its name; ObjectMissing if it is not there
        or damaged."""
        path = self.path(digest)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            raise ObjectMissing(self._missing(path)) from None
        if hashlib.sha256(data).hexdigest() != digest:
            raise ObjectMissing(f"{path} does not match its SHA-256 (damaged on disk)")
        return data

    def copy_to(self, digest: str, dest: str | os.PathLike) -> None:
        """Copies the object to `dest` (a local file), checking its hash on the way;
        ObjectMissing (and no `dest`) if it is not there or damaged."""
        path = self.path(digest)
        hasher = hashlib.sha256()
        try:
            with open(path, "rb") as src, open(dest, "wb") as out:
                while chunk := src.read(_CHUNK):
                    hasher.update(chunk)
                    out.write(chunk)
        except FileNotFoundError:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(dest)
            raise ObjectMissing(self._missing(path)) from None
        if hasher.hexdigest() != digest:
            os.unlink(dest)
            raise ObjectMissing(f"{path} does not match its SHA-256 (damaged on disk)")

    def _missing(self, path: Path) -> str:
        return (f"{path} is missing from the farm's data directory ({DATA_DIR_ENV}={self.root}): "
                f"the API and every worker must share one data directory (one machine: the same "
                f"folder; several: a shared volume)")

    # ------------------------------------------------------------------ eviction
    def evict_if_unheld(self, digest: str) -> int | None:
        """Deletes the object (index and file) if none of its holders exists; the bytes
        freed (0: no file was there), None if it is held."""
        index, holders = rdb.data_key(digest), rdb.data_holders_key(digest)
        with self.redis.pipeline(transaction=True) as pipe:
            while True:
                try:
                    pipe.watch(index, holders)
                    members = pipe.smembers(holders)
                    live = [m for m in members if self.redis.exists(m)]
                    if live:
                        dead = [m for m in members if m not in live]
                        pipe.multi()
                        if dead:
                            pipe.srem(holders, *dead)
                        pipe.execute()
                        return None
                    pipe.multi()
                    pipe.delete(index, holders)
                    pipe.srem(rdb.DATA_OBJECTS, digest)
                    pipe.execute()
                    break
                except redis.WatchError:
                    continue
        return self._remove_file(digest)

    def _remove_file(self, digest: str) -> int:
        base = self.store_dir()
        path = self.path(digest, base)
        aside = base / "tmp" / f"evicted.{digest}.{uuid.uuid4().hex[:8]}"
        try:
            os.rename(path, aside)
        except FileNotFoundError:
            return 0
        if self.redis.exists(rdb.data_key(digest)):
            # Stored again meanwhile: its writer may have seen the file and not written it.
            if not path.exists():
                os.replace(aside, path)
                return 0
        size = aside.stat().st_size
        os.unlink(aside)
        return size

    def sweep(self) -> tuple[int, int]:
        """Deletes every object that nothing holds (its file and index), and temporary
        files left by killed writers; (objects, bytes) deleted. Counted in STATS
        (data_sweeps, data_evicted, data_evicted_bytes)."""
        base = self.store_dir()
        digests = {d.decode() for d in self.redis.sscan_iter(rdb.DATA_OBJECTS)}
        with contextlib.suppress(FileNotFoundError):
            for sub in os.scandir(base / "objects"):
                if sub.is_dir():
                    digests.update(f.name for f in os.scandir(sub.path) if len(f.name) == 64)
        count = freed = 0
        for digest in sorted(digests):
            if not self.redis.exists(rdb.data_key(digest)) or not self._held(digest):
                size = self.evict_if_unheld(digest)
                if size is not None:
                    count, freed = count + 1, freed + size
        now = time.time()
        with contextlib.suppress(FileNotFoundError):
            for entry in os.scandir(base / "tmp"):
                with contextlib.suppress(FileNotFoundError):
                    if now - entry.stat().st_mtime > TMP_MAX_AGE:
                        if entry.is_dir():
                            shutil.rmtree(entry.path, ignore_errors=True)
                        else:
                            os.unlink(entry.path)
        with self.redis.pipeline(transaction=False) as pipe:
            pipe.hincrby(rdb.STATS, "data_sweeps", 1)
            if count:
                pipe.hincrby(rdb.STATS, "data_evicted", count)
                pipe.hincrby(rdb.STATS, "data_evicted_bytes", freed)
            pipe.execute()
        return count, freed

    def _held(self, digest: str) -> bool:
        return any(self.redis.exists(m) for m in self.redis.smembers(rdb.data_holders_key(digest)))


def _copy(src, out) -> None:
    with open(src, "rb") as f:
        shutil.copyfileobj(f, out, _CHUNK)
