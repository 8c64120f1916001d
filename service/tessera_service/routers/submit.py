"""POST /jobs: a scene (uploaded, or packed from stored files) and its render settings
become a job, or one job per frame: the upload, the pre-flight inspection under the
user's limits, the settings' checks. Following the job is routers/jobs.py's."""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import tempfile
import threading
import uuid
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import asdict
from pathlib import Path, PureWindowsPath
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, HTTPException, Request, Response, UploadFile
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from tessera_base import integrators, protocol
from tessera_queue import redis_schema as rdb
from tessera_base.protocol import JobSpec, RenderSettings

from ..auth import require_user
from ..inspection_pool import InspectionPool, PoolFull
from ..preflight import PreflightBroken, PreflightRejected, SceneInfo, inspect_scene, triangle_limit
from ..schemas import FrameJob, JobCreated
from ..setting_forms import settings_from_form, with_setting_forms
from ..settings import Settings
from ..store import JobStore
from ..users import User

router = APIRouter(prefix="/jobs", tags=["jobs"])
logger = logging.getLogger(__name__)

SCENE_SUFFIXES = (".usda", ".usdc", ".usdz", ".usd", ".zip")
CHUNK = 1 << 20
CurrentUser = Annotated[User, Depends(require_user)]  # as in routers/jobs.py


def upload_too_large(limit: int) -> HTTPException:
    return HTTPException(413, f"the upload is larger than the limit of {_size(limit)}")


@router.post("", status_code=201, response_model=JobCreated,
             responses={400: {"description": "not a USD file"},
                        409: {"description": "the manifest names files the farm lacks: upload them"},
                        413: {"description": "file too large"},
                        422: {"description": "invalid settings, or a scene the renderer rejects"},
                        429: {"description": "the server is inspecting as many scenes as it may; "
                                             "retry after Retry-After seconds"}})
@with_setting_forms
def create_job(
    request: Request,
    response: Response,
    user: CurrentUser,
    file: Annotated[UploadFile | None, File(
        description="the scene: .usda, .usdc, .usdz or .usd, or a .zip bundle (root layer "
                    "first); or send `manifest` instead")] = None,
    manifest: Annotated[UploadFile | None, File(
        description='instead of `file`: a packed scene, as JSON {"entry": PATH, "files": '
                    '{PATH: SHA256}} of files uploaded to PUT /blobs/SHA256 (docs/farm.md, '
                    '"Packed scenes")')] = None,
    priority: Annotated[int, Form(ge=protocol.MIN_PRIORITY, le=protocol.MAX_PRIORITY,
                                  description="0-9; higher goes first")] = protocol.DEFAULT_PRIORITY,
    max_attempts: Annotated[int, Form(ge=1, le=100, description=(
        "failed deliveries of one tile pass (errors, crashes, dead workers) before the job "
        "fails naming the tile"))] = protocol.DEFAULT_MAX_ATTEMPTS,
    frames: Annotated[str, Form(description=(
        "a frame range instead of one frame: 1-24, 1-24x2 (every second), 1,5,9 or a mix; one "
        "job per frame, and the returned id is the sequence's (GET /jobs/{id}, "
        "/jobs/{id}/frames/{frame}/image.exr; docs/farm.md)"))] = "",
    **setting_forms,  # one form field per render setting (setting_forms.with_setting_forms)
) -> JobCreated:
    settings: Settings = request.app.state.settings
    store: JobStore = request.app.state.store

    name = _file_name(file.filename) if file is not None else None
    suffix = Path(name).suffix.lower() if name is not None else ".zip"
    if suffix not in SCENE_SUFFIXES:
        raise HTTPException(400, f"unsupported file type {suffix or '(no suffix)'!r} in {name!r}: "
                                 f"upload a {', '.join(SCENE_SUFFIXES)} file")
    if (file is None) == (manifest is None):  # as FastAPI reports a missing field, naming it
        raise RequestValidationError([{
            "type": "missing", "loc": ("body", "file" if file is None else "manifest"), "input": None,
            "msg": "send the scene as `file`, or a packed scene as `manifest` (not both)"}])
    params = settings_from_form(setting_forms)
    width, height = params.pop("width", None), params.pop("height", None)
    frame_list = None
    if frames.strip():
        if params.get("frame") is not None:
            raise HTTPException(422, "send frame or frames, not both")
        try:
            frame_list = protocol.parse_frames(frames)
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from None
        if len(frame_list) > settings.max_frames:
            raise HTTPException(422, f"{len(frame_list)} frames, more than the limit of {settings.max_frames} "
                                     f"(TESSERA_MAX_FRAMES)")
    packed = _read_manifest(manifest, settings.max_upload_bytes) if manifest is not None else None
    if packed is not None:
        name = packed.scene_name   # the entry's name, packed: .zip, as the worker stores it
    if params.get("denoise"):  # the merge here denoises: refuse now rather than deliver a job without it
        from tessera_base.denoise import unavailable_reason

        if (reason := unavailable_reason()) is not None:
            raise HTTPException(422, f"denoise: this server cannot denoise: {reason}")
    # Check what can be checked before the (slow) inspection; resolution comes later.
    early = _render_settings(width=width if width is not None else 1,
                             height=height if height is not None else 1,
                             **{k: v for k, v in params.items() if k != "crop"})  # the frame size is not known yet
    # Dicing is measured at the frame the job renders: the size asked, else the stage's own
    # (which the inspection reads), through the job's camera.
    dicing = protocol.dicing_of(early)
    if dicing is not None:
        dicing.update(resolution=[width, height] if width is not None and height is not None else None,
                      camera=params.get("camera"))

    with tempfile.TemporaryDirectory(prefix=f"tessera-upload-{os.getpid()}-") as tmp:
        path = Path(tmp, protocol.scene_file_name(suffix))
        scene_hash = (_save_upload(file, path, settings.max_upload_bytes) if packed is None
                      else _assemble(request, packed, path, settings.max_upload_bytes, user))
        try:
            info = _inspect(request, path, scene_hash, params.get("variants") or (), user,
                            params.get("subdivision_level"), dicing)
        except HTTPException as exc:
            if packed is not None or suffix in (".zip", ".usdz") or exc.status_code != 422:
                raise
            raise HTTPException(422, _loose_layer_detail(str(exc.detail), path.name, name)) from None
        if params.get("camera") is not None and info.cameras is not None and params["camera"] not in info.cameras:
            raise HTTPException(422, f"camera {params['camera']} is not a Camera prim of the scene "
                                     f"(its cameras: {', '.join(info.cameras) or 'none'})")
        render = _render_settings(width=width if width is not None else info.width,
                                  height=height if height is not None else info.height, **params)
        tiles = math.ceil(render.width / render.tile_size) * math.ceil(render.height / render.tile_size)
        if tiles > settings.max_tiles:
            raise HTTPException(422, f"{render.width}x{render.height} in tiles of {render.tile_size} "
                                     f"makes {tiles} tiles, more than the limit of "
                                     f"{settings.max_tiles}: use a larger tile_size")
        footprint = rdb.job_storage_bound(render)
        if footprint > settings.job_redis_budget:
            raise HTTPException(422, f"this job would keep up to {_size(footprint)} in the farm's "
                                     f"Redis ({render.width}x{render.height}, {render.integrator}, "
                                     f"AOVs: {', '.join(render.aovs) or 'none'}), more than the "
                                     f"per-job budget of {_size(settings.job_redis_budget)} "
                                     f"(TESSERA_JOB_REDIS_BUDGET): render fewer pixels, passes or AOVs")
        store.put_scene(scene_hash, name, path)

    warnings = info.warnings if render.default_light or info.unlit_warnings is None else info.unlit_warnings
    warnings = [*warnings, *integrators.scene_warnings(render.integrator, curve_segments=info.curve_segments,
                                                           linked_lights=info.linked_lights, media=info.media)]
    if render.camera is not None:  # the inspection's choice of camera is not the job's
        warnings = [w for w in warnings if w != info.camera_note]
    if frame_list is not None and len(frame_list) > 1 and not info.animated:
        warnings = [*warnings, f"the scene has no animation (no time samples): every frame of "
                               f"frames {frames.strip()} renders the same image"]
    # Unlit by the job's setting, a light-less stage has no light to name.
    brightest = info.brightest_light if render.default_light or info.unlit_warnings is None else None
    if frame_list is not None:
        return _create_sequence(response, store, user, frame_list, scene_hash, name, render, priority,
                                max_attempts, warnings, brightest)
    spec = JobSpec(job_id=uuid.uuid4().hex, scene_hash=scene_hash, scene_name=name,
                   settings=render, priority=priority, max_attempts=max_attempts)
    tiles_total = store.create_job(spec, warnings, owner=user.name, brightest_light=brightest)
    response.headers["Location"] = f"/jobs/{spec.job_id}"
    return JobCreated(id=spec.job_id, state="queued", tiles_total=tiles_total,
                      width=render.width, height=render.height, priority=priority,
                      warnings=warnings)


def _create_sequence(response: Response, store: JobStore, user: User, frame_list: list[int], scene_hash: str,
                     name: str, render: RenderSettings, priority: int, max_attempts: int,
                     warnings: list[str], brightest: str | None = None) -> JobCreated:
    """One job per frame (its settings' frame set), then the record that lists them; a
    failure half-way cancels the frames already queued."""
    sequence_id = uuid.uuid4().hex
    created: list[tuple[int, str]] = []
    tiles_total = 0
    try:
        for f in frame_list:
            spec = JobSpec(job_id=uuid.uuid4().hex, scene_hash=scene_hash, scene_name=name,
                           settings=render.model_copy(update={"frame": float(f)}), priority=priority,
                           max_attempts=max_attempts)
            tiles_total += store.create_job(spec, warnings, owner=user.name, brightest_light=brightest,
                                            sequence=sequence_id)
            created.append((f, spec.job_id))
        store.create_sequence(sequence_id, created, name, warnings, owner=user.name)
    except BaseException:
        for _, job_id in created:
            store.cancel(job_id)
        raise
    response.headers["Location"] = f"/jobs/{sequence_id}"
    return JobCreated(id=sequence_id, state="queued", tiles_total=tiles_total, width=render.width,
                      height=render.height, priority=priority, warnings=warnings,
                      frames=[FrameJob(frame=f, job=j) for f, j in created])


def _loose_layer_detail(detail: str, stored: str, uploaded: str) -> str:
    """A refusal of a layer uploaded alone, in the uploader's terms: the layer under the name
    it was sent as (it is stored as `stored`), and, when a file it references is missing,
    that such an upload carries none of them."""
    detail = detail.replace(f"{stored}:", f"{uploaded}:")
    if "is not in the bundle" in detail:
        detail += ("; a layer uploaded alone brings none of the files it references: upload them "
                   "with it as a .zip, or send it with `tessera submit`, which packs them")
    return detail


def _inspect(request: Request, path: Path, scene_hash: str, variants: Sequence[str], user: User,
             subdivision_level: int | None = None, dicing: dict | None = None) -> SceneInfo:
    """The scene's pre-flight, composed with the job's variant selections and translated at
    its subdivision level (a level above the default multiplies what subdivision surfaces
    cost) or diced as it asks: remembered (passed or refused) for this exact file, selection,
    level and dicing, else
    inspected in a slot of the bounded pool (429 when it is full); then held to `user`'s
    limits on declared triangles and translated size."""
    settings: Settings = request.app.state.settings
    store: JobStore = request.app.state.store
    pool: InspectionPool = request.app.state.inspections
    farm_triangles = triangle_limit(settings.max_triangles, settings.preflight_memory_bytes)
    user_triangles, user_translated = settings.scene_limits(user.name)
    max_triangles = min(farm_triangles, user_triangles)
    # The user's triangle limit is the one that refused: name its setting (not in the
    # remembered verdict, which other users with the same limit share).
    why = (f" (the per-user limit: TESSERA_USER_MAX_TRIANGLES or TESSERA_USER_LIMITS)"
           if user_triangles < farm_triangles else "")
    # "/t": verdicts remembered before they carried translated_bytes are not reused.
    limits = f"{max_triangles}/{settings.preflight_memory_bytes}/{settings.preflight_timeout:g}/t"
    if subdivision_level is not None:
        limits += f"/s{subdivision_level}"
    elif dicing is not None:
        limits += "/d" + hashlib.sha256(json.dumps(dicing, sort_keys=True).encode()).hexdigest()[:16]
    info = _inspect_limited(request, path, scene_hash, variants, max_triangles, limits, why, subdivision_level,
                            dicing)
    if info.translated_bytes > user_translated:
        raise HTTPException(422, f"the scene cannot be rendered: it translates to "
                                 f"{_size(info.translated_bytes)}, more than the "
                                 f"{_size(user_translated)} a scene of yours may "
                                 f"(TESSERA_USER_MAX_TRANSLATED_BYTES or TESSERA_USER_LIMITS)")
    return info


def _inspect_limited(request: Request, path: Path, scene_hash: str, variants: Sequence[str],
                     max_triangles: int, limits: str, why: str, subdivision_level: int | None = None,
                     dicing: dict | None = None) -> SceneInfo:
    settings: Settings = request.app.state.settings
    store: JobStore = request.app.state.store
    pool: InspectionPool = request.app.state.inspections
    # Concurrent uploads of one scene wait for a single inspection.
    with _inspection_lock(scene_hash):
        cached = store.preflight(scene_hash, path.suffix, limits, variants)
        if cached is not None and "error" in cached:
            raise HTTPException(422, f"the scene cannot be rendered: {cached['error']}"
                                     + (why if str(max_triangles) in cached["error"] else ""))
        if cached is not None:  # this exact file was inspected before: skip the child
            return SceneInfo(**cached)
        try:
            with pool.slot():
                try:
                    info = inspect_scene(str(path), timeout=settings.preflight_timeout,
                                         memory_bytes=settings.preflight_memory_bytes,
                                         max_triangles=max_triangles,
                                         variants=[protocol.parse_variant(v) for v in variants],
                                         subdivision_level=subdivision_level, dicing=dicing)
                except PreflightRejected as e:
                    store.count_inspection(rejected=True)
                    if e.lasting:  # (a timeout under load says nothing of the file)
                        store.remember_rejection(scene_hash, path.suffix, str(e), limits, variants)
                    raise HTTPException(422, f"the scene cannot be rendered: {e}"
                                             + (why if str(max_triangles) in str(e) else "")) from None
                except PreflightBroken as e:  # the server's fault: not remembered
                    raise HTTPException(500, str(e)) from None
        except PoolFull as e:
            raise HTTPException(429, str(e), headers={"Retry-After": "5"}) from None
        store.count_inspection(rejected=False)
        store.remember_preflight(scene_hash, path.suffix, asdict(info), limits, variants)
        return info


_locks_guard = threading.Lock()


_locks: dict[str, threading.Lock] = {}


@contextmanager
def _inspection_lock(scene_hash: str):
    with _locks_guard:
        lock = _locks.setdefault(scene_hash, threading.Lock())
    with lock:
        yield
    with _locks_guard:
        if not lock.locked():
            _locks.pop(scene_hash, None)


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


def _read_manifest(upload: UploadFile, limit: int):
    """A packed scene's manifest (tessera_service.blobs), refused with a 422 in the user's terms."""
    from ..blobs import ManifestError, parse_manifest

    data = upload.file.read(limit + 1)
    if len(data) > limit:
        raise upload_too_large(limit)
    try:
        return parse_manifest(data)
    except ManifestError as exc:
        raise HTTPException(422, f"manifest: {exc}") from None


def _assemble(request: Request, packed, path: Path, limit: int, user: User) -> str:
    """Builds a packed scene's bundle from the stored files; 409 naming the files the farm
    lacks (the client uploads them and posts again)."""
    from ..blobs import BlobsMissing, BlobStore, ManifestError

    blobs = BlobStore(request.app.state.store.redis, request.app.state.settings.scene_retention,
                      user.name, request.app.state.store.data)
    try:
        return blobs.assemble(packed, path, limit)
    except BlobsMissing as exc:
        raise HTTPException(409, str(exc)) from None
    except ManifestError as exc:
        raise HTTPException(422, f"manifest: {exc}") from None


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
