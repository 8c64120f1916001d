"""/blobs: the content-addressed files of packed scenes (tessera_service.blobs). A client
asks which of its files' hashes the farm lacks, uploads only those, then submits the
manifest to POST /jobs."""
from __future__ import annotations

import hashlib
import os
import tempfile
from contextlib import contextmanager
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Request
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from ..auth import require_user
from ..blobs import HASH, MAX_FILES, BlobStore, QuotaExceeded
from ..users import User

CurrentUser = Annotated[User, Depends(require_user)]

router = APIRouter(prefix="/blobs", tags=["blobs"])


class HashList(BaseModel):
    hashes: list[str] = Field(max_length=MAX_FILES, description="SHA-256 (lower-case hex) of each file")


class MissingHashes(BaseModel):
    missing: list[str] = Field(description="the hashes the farm does not store: upload these")


class BlobStored(BaseModel):
    hash: str
    size: int
    stored: bool = Field(description="false when the farm had these bytes already")


def _blobs(request: Request, user: User) -> BlobStore:
    return BlobStore(request.app.state.store.redis, request.app.state.settings.scene_retention,
                     user.name, request.app.state.store.data)


@router.post("/missing", response_model=MissingHashes)
def missing_blobs(body: HashList, request: Request, user: CurrentUser) -> MissingHashes:
    """Which of these files the farm lacks for you: a file you have not uploaded yourself
    counts as lacking, whoever else did. Those it has are kept for another scene
    retention from now."""
    for digest in body.hashes:
        if not HASH.fullmatch(digest):
            raise HTTPException(422, f"{digest[:80]!r} is not a SHA-256 in lower-case hex")
    return MissingHashes(missing=_blobs(request, user).missing(body.hashes))


@router.put("/{digest}", status_code=201, response_model=BlobStored,
            responses={413: {"description": "larger than the upload limit, or past the user's "
                                             "quota of stored files"},
                       429: {"description": "too many uploads in flight (the user's or the farm's); "
                                            "Retry-After says when to try again"},
                       422: {"description": "the bytes do not have this hash"}},
            openapi_extra={"requestBody": {"required": True,
                                           "content": {"application/octet-stream": {"schema": {
                                               "type": "string", "format": "binary"}}}}})
async def put_blob(digest: str, request: Request, user: CurrentUser) -> BlobStored:
    """Stores one file under its SHA-256, which is checked against the bytes received."""
    if not HASH.fullmatch(digest):
        raise HTTPException(422, f"{digest[:80]!r} is not a SHA-256 in lower-case hex")
    limit = request.app.state.settings.max_upload_bytes
    too_large = HTTPException(413, f"the file is larger than the upload limit of {limit} bytes")
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > limit:
        raise too_large
    with upload_slot(request, user):
        return await _receive_blob(digest, request, user, limit, too_large)


@contextmanager
def upload_slot(request: Request, user: User):
    """One of the user's and the farm's uploads in flight, or 429 with Retry-After. Without
    a bound, one user's many slow uploads each held a temporary file of up to the upload
    limit (and a connection) for as long as they liked."""
    settings = request.app.state.settings
    in_flight: dict[str, int] = request.app.state.uploads_in_flight
    mine, total = in_flight.get(user.name, 0), sum(in_flight.values())
    if mine >= settings.user_upload_concurrency or total >= settings.upload_concurrency:
        which = (f"you have {mine} uploads in flight, the most one user may have "
                 f"(TESSERA_USER_UPLOAD_CONCURRENCY)" if mine >= settings.user_upload_concurrency
                 else f"the farm has {total} uploads in flight, the most it takes (TESSERA_UPLOAD_CONCURRENCY)")
        raise HTTPException(429, f"{which}: send this file when one of them has finished",
                            headers={"Retry-After": "1"})
    in_flight[user.name] = mine + 1
    try:
        yield
    finally:
        left = in_flight[user.name] - 1
        if left:
            in_flight[user.name] = left
        else:
            del in_flight[user.name]


async def _receive_blob(digest: str, request: Request, user: User, limit: int,
                        too_large: HTTPException) -> BlobStored:
    # Streamed to disk and hashed on the way: held in memory, 8 concurrent 250 MiB PUTs
    # with a wrong hash took the API to 2,157 MiB. Only verified bytes are copied into the
    # data directory, in one of a few slots (settings.blob_store_concurrency).
    hasher = hashlib.sha256()
    size = 0
    with tempfile.TemporaryDirectory(prefix=f"tessera-upload-{os.getpid()}-") as tmp:
        path = os.path.join(tmp, "blob")
        with open(path, "wb") as out:
            async for chunk in request.stream():
                size += len(chunk)
                if size > limit:
                    raise too_large
                hasher.update(chunk)
                out.write(chunk)
        if hasher.hexdigest() != digest:
            raise HTTPException(422, f"the uploaded bytes have SHA-256 {hasher.hexdigest()}, not {digest}: "
                                     f"the file changed or was damaged on the way; nothing was stored")
        async with request.app.state.blob_slots:
            # The store is the synchronous client: off the event loop, as the sync routes are.
            try:
                stored = await run_in_threadpool(_store_file, _blobs(request, user), digest, path,
                                                 request.app.state.settings.user_blob_quota_bytes)
            except QuotaExceeded as exc:
                raise HTTPException(413, str(exc)) from None
    return BlobStored(hash=digest, size=size, stored=stored)


def _store_file(blobs: BlobStore, digest: str, path: str, quota: int) -> bool:
    return blobs.put(digest, path, quota)


class BlobsDeleted(BaseModel):
    files: int = Field(description="files of yours deleted")
    bytes: int = Field(description="their total size")
    quota: int = Field(description="your quota of stored files in bytes")


@router.delete("/{digest}", response_model=BlobsDeleted,
               responses={404: {"description": "you have no file with this hash"}})
def delete_blob(digest: str, request: Request, user: CurrentUser) -> BlobsDeleted:
    """Deletes one of your stored files (freeing your quota; the bytes stay while another
    user who sent them keeps them). Submitted jobs are not affected."""
    if not HASH.fullmatch(digest):
        raise HTTPException(422, f"{digest[:80]!r} is not a SHA-256 in lower-case hex")
    size = _blobs(request, user).delete(digest)
    if size is None:
        raise HTTPException(404, f"you have no stored file {digest}")
    return BlobsDeleted(files=1, bytes=size, quota=request.app.state.settings.user_blob_quota_bytes)


@router.delete("", response_model=BlobsDeleted)
def delete_blobs(request: Request, user: CurrentUser) -> BlobsDeleted:
    """Deletes all of your stored files. Submitted jobs are not affected."""
    files, size = _blobs(request, user).delete_all()
    return BlobsDeleted(files=files, bytes=size, quota=request.app.state.settings.user_blob_quota_bytes)
