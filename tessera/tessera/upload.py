"""Content-addressed upload of a packed scene (the client's side of tessera_service.blobs):
hash every file of the pack, ask the API which hashes it lacks, upload only those, then
submit the manifest (relative path -> hash) with the job. A second submit of the same
scene with one changed texture uploads only that texture."""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

CHUNK = 1 << 20


@dataclass
class UploadReport:
    """What a packed submit sent. `files`/`bytes`: the whole pack; `uploaded_*`: what went
    over the wire (the rest was on the farm already)."""

    files: int = 0
    bytes: int = 0
    uploaded_files: int = 0
    uploaded_bytes: int = 0
    uploaded: list[str] = field(default_factory=list)   # relative paths, in upload order

    def summary(self) -> str:
        return (f"packed {self.files} file(s), {_size(self.bytes)}; uploaded {self.uploaded_files} "
                f"({_size(self.uploaded_bytes)}), {self.files - self.uploaded_files} already on the farm")


def _size(n: int) -> str:
    """Exact, and readable when large."""
    return f"{n} bytes" if n < 10_000 else f"{n} bytes = {n / 1e6:.2f} MB"


class UploadError(RuntimeError):
    """The server refused part of the upload; the message says which and why."""


def file_hash(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def submit_packed(client: httpx.Client, files: dict[str, Path], entry: str,
                  form: dict[str, str]) -> tuple[httpx.Response, UploadReport]:
    """Uploads what the farm lacks of `files` (relative path -> file) and posts the job
    (POST /jobs with the manifest instead of a file). Returns the job response (the caller
    reads its status code) and what was sent. If files expire between the question and
    the job (a 409), they are uploaded again, once."""
    hashes = {rel: file_hash(path) for rel, path in files.items()}
    report = UploadReport(files=len(files), bytes=sum(p.stat().st_size for p in files.values()))
    manifest = json.dumps({"entry": entry, "files": hashes}, sort_keys=True).encode()
    for _attempt in range(2):
        _upload_missing(client, files, hashes, report)
        r = client.post("/jobs", files={"manifest": ("manifest.json", manifest, "application/json")},
                        data=form)
        if r.status_code != 409:
            break
    return r, report


def _upload_missing(client: httpx.Client, files: dict[str, Path], hashes: dict[str, str],
                    report: UploadReport) -> None:
    r = client.post("/blobs/missing", json={"hashes": sorted(set(hashes.values()))})
    if r.status_code != 200:
        raise UploadError(f"the server cannot take packed scenes ({r.status_code}): {_detail(r)}")
    missing = set(r.json()["missing"])
    for rel, digest in hashes.items():
        if digest not in missing:
            continue
        missing.discard(digest)  # one upload per content, however many paths share it
        put = _put_file(client, digest, files[rel])
        if put.status_code not in (200, 201):
            raise UploadError(f"{rel}: the server refused the file ({put.status_code}): {_detail(put)}")
        report.uploaded_files += 1
        report.uploaded_bytes += put.json()["size"]
        report.uploaded.append(rel)


# A farm whose uploads in flight are at their bound answers 429 with Retry-After (the
# user's or the farm's TESSERA_*UPLOAD_CONCURRENCY): wait as told, a bounded number of times.
UPLOAD_RETRIES = 60
MAX_RETRY_WAIT = 5.0


def _put_file(client: httpx.Client, digest: str, path: Path) -> httpx.Response:
    for attempt in range(UPLOAD_RETRIES + 1):
        with open(path, "rb") as f:
            put = client.put(f"/blobs/{digest}", content=f, headers={"Content-Type": "application/octet-stream"})
        if put.status_code != 429 or attempt == UPLOAD_RETRIES:
            return put
        try:
            wait = float(put.headers.get("retry-after", "1"))
        except ValueError:
            wait = 1.0
        time.sleep(min(max(wait, 0.1), MAX_RETRY_WAIT))
    return put


def _detail(response: httpx.Response) -> str:
    try:
        return str(response.json().get("detail"))
    except ValueError:
        return response.text[:200]
