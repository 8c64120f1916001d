"""Content-addressed scene files (as Flamenco's Shaman does): a client uploads only the
files the farm lacks, by SHA-256, then posts a manifest (relative path -> hash) naming
the entry layer; the service assembles the bundle from the stored files.

The assembled bundle is a zip, laid out as the manifest says, with the entry layer first
and named in the archive comment (`tessera-entry: PATH`, read by the renderer's bundle
sandbox), so that it is an ordinary .zip upload from there on: the same pre-flight, the
same sandbox (a path escaping the bundle is refused), the same scene lifetime. The zip is
byte-for-byte a function of the manifest and the files (fixed dates, stored members,
sorted order), so the same scene packed twice is the same scene hash and its pre-flight
is remembered.

Limits: one file is at most `max_upload_bytes`, as is the whole bundle (a packed scene is
an upload); a manifest names at most TESSERA_MAX_FILES files (the bundle sandbox's own
limit, 20 000). Files are kept for the scene retention after their last use, or until
their user deletes them; each user may keep `user_blob_quota_bytes` of files. Their bytes
live in the data store (tessera_queue.data_store), held by their index in Redis
(`redis_schema.blob_key`); a job does not hold them, since its bundle is a copy (a scene
of its own, which the job holds).

Ownership: the bytes are stored once, but a user may use a file only after sending its
bytes themselves (`redis_schema.blob_owners_key`); to another user the farm answers that
it lacks the file. A user who uploads bytes the farm holds already sends them in full
(stored: false) and so proves having them.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import redis

from tessera_queue import redis_schema as rdb
from tessera_queue.data_store import DataStore, ObjectMissing

HASH = re.compile(r"[0-9a-f]{64}")
ENTRY_COMMENT = "tessera-entry: "
LAYER_SUFFIXES = (".usda", ".usdc", ".usd", ".usdz")
# The bundle sandbox's file limit (tessera_renderer.usd.bundle.Limits.files; the API does not
# import the renderer): a manifest cannot name more files than the pre-flight would unpack.
MAX_FILES = int(os.environ.get("TESSERA_MAX_FILES", 20_000) or 20_000)
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


class ManifestError(ValueError):
    """A manifest the service refuses; the message is for the user."""


class QuotaExceeded(Exception):
    """The upload would take the user past their blob quota; the message is for the user."""


class BlobsMissing(ManifestError):
    """The manifest names files that are not (or no longer) stored."""

    def __init__(self, missing: dict[str, str]):
        self.missing = missing
        names = ", ".join(list(missing)[:5]) + (" ..." if len(missing) > 5 else "")
        super().__init__(f"{len(missing)} file(s) of the manifest are not on the farm (never uploaded, "
                         f"or expired): {names}; upload them (PUT /blobs/<sha256>) and post again")


@dataclass
class Manifest:
    entry: str
    files: dict[str, str]   # relative POSIX path -> sha256 hex

    @property
    def scene_name(self) -> str:
        """The job's scene name: the entry layer's file name, packed."""
        return f"{PurePosixPath(self.entry).name}.zip"


def parse_manifest(data: bytes) -> Manifest:
    """The manifest JSON {"entry": PATH, "files": {PATH: SHA256}}, with every path checked
    to stay inside the bundle."""
    try:
        value = json.loads(data)
    except (ValueError, RecursionError) as exc:
        raise ManifestError(f"the manifest is not JSON: {exc}") from None
    if not isinstance(value, dict) or not isinstance(value.get("files"), dict) \
            or not isinstance(value.get("entry"), str):
        raise ManifestError('the manifest must be {"entry": "scene.usda", "files": {"scene.usda": "<sha256>", ...}}')
    files: dict[str, str] = {}
    folded: dict[str, str] = {}
    if len(value["files"]) > MAX_FILES:
        raise ManifestError(f"the manifest names {len(value['files'])} files, more than the limit of "
                            f"{MAX_FILES} (TESSERA_MAX_FILES)")
    for path, digest in value["files"].items():
        name = _member_path(path)
        if not isinstance(digest, str) or not HASH.fullmatch(digest):
            raise ManifestError(f"manifest entry {path!r}: {digest!r} is not a SHA-256 in lower-case hex")
        if name in files or name.lower() in folded:
            # Two names for one place (or ones that collide on a case-insensitive disk).
            raise ManifestError(f"manifest entry {path!r} duplicates {folded.get(name.lower(), name)!r}")
        files[name] = digest
        folded[name.lower()] = path
    if not files:
        raise ManifestError("the manifest names no files")
    prefixes = {"/".join(p.split("/")[:i]) for p in files for i in range(1, p.count("/") + 1)}
    if clash := prefixes & set(files):
        raise ManifestError(f"manifest entry {sorted(clash)[0]!r} is both a file and a folder")
    entry = _member_path(value["entry"])
    if entry not in files:
        raise ManifestError(f"the entry layer {value['entry']!r} is not among the manifest's files")
    if PurePosixPath(entry).suffix.lower() not in LAYER_SUFFIXES:
        raise ManifestError(f"the entry {value['entry']!r} is not a USD layer ({', '.join(LAYER_SUFFIXES)})")
    return Manifest(entry=entry, files=files)


def _member_path(path) -> str:
    """A relative path that stays inside the bundle, as a zip member name."""
    if not isinstance(path, str) or not path or len(path) > 4096:
        raise ManifestError(f"manifest path {path!r} is not a file path")
    if "\x00" in path or "\\" in path or path.startswith("/") or re.match(r"^[A-Za-z][A-Za-z0-9+.\-]*:", path):
        raise ManifestError(f"manifest path {path!r} is absolute or invalid; paths are relative, with '/'")
    parts = PurePosixPath(path).parts
    if ".." in parts:
        raise ManifestError(f"manifest path {path!r} escapes the bundle with '..'")
    clean = [p for p in parts if p != "."]
    if not clean or path.endswith("/"):
        raise ManifestError(f"manifest path {path!r} names no file")
    return "/".join(clean)


class BlobStore:
    """The API's side of content-addressed files: their index in Redis
    (`redis_schema.blob_key`), their bytes in the data store."""

    def __init__(self, client: redis.Redis, retention: float, user: str, data: DataStore):
        self.redis = client
        self.ttl = int(retention) if retention > 0 else 0
        self.user = user
        self.data = data

    def _owned(self, hashes: list[str]) -> list[bool]:
        """Whether each file is stored and this user sent its bytes."""
        with self.redis.pipeline(transaction=False) as pipe:
            for digest in hashes:
                pipe.exists(rdb.blob_key(digest))
                pipe.sismember(rdb.blob_owners_key(digest), self.user)
            replies = pipe.execute()
        return [bool(stored and mine) for stored, mine in zip(replies[0::2], replies[1::2])]

    def _renew(self, hashes: list[str]) -> None:
        if self.ttl:
            with self.redis.pipeline(transaction=False) as pipe:
                for digest in hashes:
                    pipe.expire(rdb.blob_key(digest), self.ttl)
                    pipe.expire(rdb.blob_owners_key(digest), self.ttl)
                pipe.execute()

    def missing(self, hashes: list[str]) -> list[str]:
        """Those of `hashes` this user cannot use: not stored, or stored from another
        user's upload (which is not said); the usable ones have their retention renewed,
        so they outlive the upload of the rest."""
        unique = list(dict.fromkeys(hashes))
        owned = self._owned(unique)
        self._renew([d for d, ok in zip(unique, owned) if ok])
        return [d for d, ok in zip(unique, owned) if not ok]

    def usage(self) -> int:
        """Bytes of the blobs this user sent that are still stored; drops the entries of
        those that expired."""
        usage_key = rdb.blob_usage_key(self.user)
        sizes = {d.decode(): int(n) for d, n in self.redis.hgetall(usage_key).items()}
        if not sizes:
            return 0
        owned = dict(zip(sizes, self._owned(list(sizes))))
        if gone := [d for d, ok in owned.items() if not ok]:
            self.redis.hdel(usage_key, *gone)
        return sum(n for d, n in sizes.items() if owned[d])

    def put(self, digest: str, path: str | os.PathLike, quota: int | None = None) -> bool:
        """Stores the verified file at `path` as `digest` and records that this user has
        it; False when it was stored already. QuotaExceeded when bytes the user does not
        have yet would take them past `quota` (checked against their usage now: concurrent
        uploads of one user may pass it by what they upload at once, at most
        blob_store_concurrency files per API process)."""
        size = os.path.getsize(path)
        if quota is not None and not self._owned([digest])[0]:
            used = self.usage()
            if used + size > quota:
                raise QuotaExceeded(
                    f"this file ({size} bytes) would take your stored files to "
                    f"{used + size} bytes, more than your quota of {quota} bytes "
                    f"(TESSERA_USER_BLOB_QUOTA_BYTES): delete files you no longer need "
                    f"(DELETE /blobs/<sha256>, or DELETE /blobs for all of yours), or wait for "
                    f"them to expire")
        usage_key, blob = rdb.blob_usage_key(self.user), rdb.blob_key(digest)
        with self.redis.pipeline(transaction=True) as pipe:
            pipe.set(blob, size, nx=True, ex=self.ttl or None)
            pipe.sadd(rdb.blob_owners_key(digest), self.user)
            pipe.hset(usage_key, digest, size)
            if self.ttl:
                pipe.expire(usage_key, self.ttl)
            self.data.hold(pipe, digest, size, blob)  # index first: see data_store
            stored = pipe.execute()[0]
        self._renew([digest])
        self.data.write_file(digest, path)
        return bool(stored)

    def delete(self, digest: str) -> int | None:
        """Forgets that this user has the file, and the file itself (its bytes in the data
        store at once) once no other user sent it; its size, or None when this user has
        no such file. Jobs are not affected: a submitted packed scene is a scene of its own
        (assembled at submission)."""
        owners, blob = rdb.blob_owners_key(digest), rdb.blob_key(digest)
        with self.redis.pipeline(transaction=True) as pipe:
            while True:
                try:
                    pipe.watch(owners)  # another user's upload of these bytes meanwhile: retry
                    if not pipe.sismember(owners, self.user) or not pipe.exists(blob):
                        pipe.unwatch()
                        self.redis.hdel(rdb.blob_usage_key(self.user), digest)
                        return None
                    size = self._size(digest, pipe.get(blob))
                    last = int(pipe.scard(owners)) == 1
                    pipe.multi()
                    pipe.srem(owners, self.user)
                    pipe.hdel(rdb.blob_usage_key(self.user), digest)
                    if last:
                        pipe.delete(blob, owners)
                    pipe.execute()
                    break
                except redis.WatchError:
                    continue
        if last:
            self.data.evict_if_unheld(digest)
        return size

    def delete_all(self) -> tuple[int, int]:
        """Deletes every file this user sent (as `delete`); (files, bytes)."""
        files = total = 0
        for digest in self.redis.hkeys(rdb.blob_usage_key(self.user)):
            size = self.delete(digest.decode())
            if size is not None:
                files, total = files + 1, total + size
        return files, total

    def sizes(self, hashes: list[str]) -> dict[str, int]:
        with self.redis.pipeline(transaction=False) as pipe:
            for digest in hashes:
                pipe.get(rdb.blob_key(digest))
            return {d: self._size(d, raw) for d, raw in zip(hashes, pipe.execute())}

    def _size(self, digest: str, raw: bytes | None) -> int:
        """The size a blob's index says; a blob stored by a farm before the data store (its
        bytes in the index itself) is moved into the data store first."""
        if raw is None:
            return 0
        if raw.isdigit():
            return int(raw)
        if hashlib.sha256(raw).hexdigest() != digest:
            return 0  # damaged: never usable
        blob = rdb.blob_key(digest)
        with self.redis.pipeline(transaction=True) as pipe:
            self.data.hold(pipe, digest, len(raw), blob)  # index first: see data_store
            pipe.set(blob, len(raw), xx=True, keepttl=True)
            pipe.execute()
        self.data.write_bytes(digest, raw)
        return len(raw)

    def assemble(self, manifest: Manifest, out: Path, limit: int) -> str:
        """Writes the manifest's bundle to `out` (a zip; see the module docstring) and
        returns its SHA-256. Every file is checked against its hash again as it is read,
        and the bundle against `limit` bytes before anything is read."""
        unique = list(dict.fromkeys(manifest.files.values()))
        sizes = self.sizes(unique)
        usable = dict(zip(unique, self._owned(unique)))
        gone = {p: d for p, d in manifest.files.items() if not usable[d]}
        if gone:
            raise BlobsMissing(gone)
        total = sum(sizes[d] for d in manifest.files.values())
        if total > limit:
            raise ManifestError(f"the packed scene is {total} bytes, more than the upload limit of "
                                f"{limit} bytes (TESSERA_MAX_UPLOAD_BYTES)")
        order = [manifest.entry] + sorted(p for p in manifest.files if p != manifest.entry)
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:
            zf.comment = (ENTRY_COMMENT + manifest.entry).encode()
            for name in order:
                digest = manifest.files[name]
                try:
                    data = self.data.read_bytes(digest)  # checked against its hash
                except ObjectMissing:
                    raise BlobsMissing({name: digest}) from None
                info = zipfile.ZipInfo(name, date_time=_ZIP_DATE)
                info.create_system = 3
                info.external_attr = 0o644 << 16
                zf.writestr(info, data)
        self._renew(unique)
        digest = hashlib.sha256()
        with open(out, "rb") as f:
            while chunk := f.read(1 << 20):
                digest.update(chunk)
        return digest.hexdigest()
