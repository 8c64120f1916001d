"""/jobs: submit a scene, follow the job, download the image, cancel."""
from __future__ import annotations

import hashlib
import math
import tempfile
import time
import uuid
from datetime import datetime, timezone
from pathlib import Path, PureWindowsPath
from typing import Annotated

from fastapi import APIRouter, File, Form, HTTPException, Request, Response, UploadFile
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from tessera.protocol import JobSpec, RenderSettings

from ..merge import MergeError, encode_images, merge_tiles
from ..preflight import PreflightBroken, PreflightRejected, inspect_scene
from ..schemas import JobCreated, JobStatus
from ..settings import Settings
from ..store import Job, JobStore

router = APIRouter(prefix="/jobs", tags=["jobs"])

SCENE_SUFFIXES = (".usda", ".usdc", ".usdz", ".usd")
CHUNK = 1 << 20
_DEFAULTS = {name: f.default for name, f in RenderSettings.model_fields.items()}


def upload_too_large(limit: int) -> HTTPException:
    return HTTPException(413, f"the upload is larger than the limit of {_size(limit)}")


@router.post("", status_code=201, response_model=JobCreated,
             responses={400: {"description": "not a USD file"},
                        413: {"description": "file too large"},
                        422: {"description": "invalid settings, or a scene the renderer rejects"}})
def create_job(
    request: Request,
    response: Response,
    file: Annotated[UploadFile, File(description="the scene: .usda, .usdc, .usdz or .usd")],
    width: Annotated[int | None, Form(description="default: the scene's render settings, else 512")] = None,
    height: Annotated[int | None, Form(description="default: the scene's render settings, else 512")] = None,
    spp: Annotated[int, Form(description="samples per pixel")] = _DEFAULTS["spp"],
    seed: Annotated[int, Form()] = _DEFAULTS["seed"],
    max_depth: Annotated[int, Form(description="maximum path length")] = _DEFAULTS["max_depth"],
    tile_size: Annotated[int, Form(description="tile edge in pixels")] = _DEFAULTS["tile_size"],
) -> JobCreated:
    settings: Settings = request.app.state.settings
    store: JobStore = request.app.state.store

    name = _file_name(file.filename)
    suffix = Path(name).suffix.lower()
    if suffix not in SCENE_SUFFIXES:
        raise HTTPException(400, f"unsupported file type {suffix or '(no suffix)'!r} in {name!r}: "
                                 f"upload a {', '.join(SCENE_SUFFIXES)} file")
    params = dict(spp=spp, seed=seed, max_depth=max_depth, tile_size=tile_size)
    # Check what can be checked before the (slow) inspection; resolution comes later.
    _render_settings(width=width if width is not None else 1,
                     height=height if height is not None else 1, **params)

    with tempfile.TemporaryDirectory(prefix="tessera-upload-") as tmp:
        path = Path(tmp, f"scene{suffix}")
        scene_hash = _save_upload(file, path, settings.max_upload_bytes)
        try:
            info = inspect_scene(str(path), timeout=settings.preflight_timeout,
                                 memory_bytes=settings.preflight_memory_bytes)
        except PreflightRejected as e:
            raise HTTPException(422, f"the scene cannot be rendered: {e}") from None
        except PreflightBroken as e:
            raise HTTPException(500, str(e)) from None
        render = _render_settings(width=width if width is not None else info.width,
                                  height=height if height is not None else info.height, **params)
        tiles = math.ceil(render.width / render.tile_size) * math.ceil(render.height / render.tile_size)
        if tiles > settings.max_tiles:
            raise HTTPException(422, f"{render.width}x{render.height} in tiles of {render.tile_size} "
                                     f"makes {tiles} tiles, more than the limit of "
                                     f"{settings.max_tiles}: use a larger tile_size")
        store.put_scene(scene_hash, name, path.read_bytes())

    spec = JobSpec(job_id=uuid.uuid4().hex, scene_hash=scene_hash, scene_name=name, settings=render)
    tiles_total = store.create_job(spec, info.warnings)
    response.headers["Location"] = f"/jobs/{spec.job_id}"
    return JobCreated(id=spec.job_id, state="queued", tiles_total=tiles_total,
                      width=render.width, height=render.height, warnings=info.warnings)


@router.get("/{job_id}", response_model=JobStatus, responses={404: {"description": "no such job"}})
def get_job(job_id: str, request: Request) -> JobStatus:
    return _status(job_id, _job(request, job_id))


@router.delete("/{job_id}", response_model=JobStatus, responses={404: {"description": "no such job"}})
def cancel_job(job_id: str, request: Request) -> JobStatus:
    """Cancels a queued or running job; a finished job is left as it is."""
    store: JobStore = request.app.state.store
    if not store.cancel(job_id):
        raise _not_found(job_id)
    return _status(job_id, _job(request, job_id))


@router.get("/{job_id}/image.exr", response_class=Response,
            responses={200: {"content": {"image/x-exr": {}}}, 404: {}, 409: {"description": "not done"}})
def get_image(job_id: str, request: Request) -> Response:
    """The rendered image: float linear RGBA OpenEXR."""
    data = _image(request, job_id, "exr")
    return Response(data, media_type="image/x-exr",
                    headers={"Content-Disposition": f'attachment; filename="{job_id}.exr"'})


@router.get("/{job_id}/preview.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 404: {}, 409: {"description": "not done"}})
def get_preview(job_id: str, request: Request) -> Response:
    """A tonemapped 8-bit sRGB preview of the image."""
    data = _image(request, job_id, "png")
    return Response(data, media_type="image/png",
                    headers={"Content-Disposition": f'inline; filename="{job_id}.png"'})


# ---------------------------------------------------------------------------- helpers
def _job(request: Request, job_id: str) -> Job:
    job = request.app.state.store.get(job_id)
    if job is None:
        raise _not_found(job_id)
    return job


def _not_found(job_id: str) -> HTTPException:
    return HTTPException(404, f"no job with id {job_id!r}")


def _image(request: Request, job_id: str, fmt: str) -> bytes:
    store: JobStore = request.app.state.store
    job = _job(request, job_id)
    if job.state != "done":
        detail = f"job {job_id} is {job.state}; its image is available once it is done"
        if job.error:
            detail += f" (error: {job.error})"
        raise HTTPException(409, detail)
    data = store.cached_image(job_id, fmt)
    if data is None:
        try:
            rgba = merge_tiles(job.spec, store.tiles(job_id))
        except MergeError as e:
            raise HTTPException(500, f"cannot assemble the image of job {job_id}: {e}") from None
        exr, png = encode_images(rgba, job.spec)
        store.cache_images(job_id, exr, png)
        data = exr if fmt == "exr" else png
    return data


def _status(job_id: str, job: Job) -> JobStatus:
    def when(t: float | None) -> datetime | None:
        return datetime.fromtimestamp(t, timezone.utc) if t is not None else None

    end = job.finished_at if job.finished_at is not None else time.time()
    return JobStatus(
        id=job_id, state=job.state, scene_name=job.spec.scene_name, settings=job.spec.settings,
        tiles_done=job.tiles_done, tiles_total=job.tiles_total,
        created_at=when(job.created_at), started_at=when(job.started_at),
        finished_at=when(job.finished_at),
        elapsed_seconds=round(max(0.0, end - job.created_at), 3),
        render_seconds=round(job.render_seconds, 3),
        warnings=job.warnings, error=job.error)


def _render_settings(**values) -> RenderSettings:
    """RenderSettings from form values; invalid values are a 422 naming the field."""
    try:
        return RenderSettings(**values)
    except ValidationError as e:
        raise RequestValidationError(
            [{**err, "loc": ("body", *err["loc"])} for err in e.errors(include_url=False)]) from None


def _file_name(raw: str | None) -> str:
    """The uploaded file's base name, without any client-side directories."""
    name = PureWindowsPath(raw or "").name  # handles both / and \\ separators
    name = "".join(c for c in name if c.isprintable())[-200:]
    if not name:
        raise HTTPException(400, "the upload has no file name; name the file *.usda, *.usdc, "
                                 "*.usdz or *.usd")
    return name


def _save_upload(upload: UploadFile, path: Path, limit: int) -> str:
    """Copies the upload to path, enforcing the size limit; returns its sha256."""
    digest = hashlib.sha256()
    size = 0
    with open(path, "wb") as out:
        while chunk := upload.file.read(CHUNK):
            size += len(chunk)
            if size > limit:
                raise upload_too_large(limit)
            digest.update(chunk)
            out.write(chunk)
    return digest.hexdigest()


def _size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:g} {unit} ({n} bytes)"
    return f"{n} bytes"
