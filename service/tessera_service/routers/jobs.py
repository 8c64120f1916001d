"""/jobs: submit a scene, follow the job (status, events, log, preview), download the
image, cancel, pause, resume."""
from __future__ import annotations

import asyncio
import os
import hashlib
import json
import logging
import math
import re
import tempfile
import threading
import time
import uuid
from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path, PureWindowsPath
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, HTTPException, Query, Request, Response, UploadFile
from fastapi.exceptions import RequestValidationError
from fastapi.responses import StreamingResponse
from pydantic import ValidationError

from tessera_base import integrators, protocol
from tessera_queue import redis_schema as rdb
from tessera_base.film import black_image_warning
from tessera_base.protocol import FINAL_STATES, JobSpec, JobState, RenderSettings

from ..auth import require_user
from ..merge import MergeError, denoised_png, encode_image, merge_tiles, read_denoised, reached_noise
from ..inspection_pool import InspectionPool, PoolFull
from ..preflight import PreflightBroken, PreflightRejected, SceneInfo, inspect_scene, triangle_limit
from ..schemas import FrameJob, JobCreated, JobList, JobLog, JobStatus, SequenceStatus
from ..sequences import sequence_status
from ..settings import Settings
from ..store import Job, JobStore
from ..users import User

router = APIRouter(prefix="/jobs", tags=["jobs"])
logger = logging.getLogger(__name__)

SCENE_SUFFIXES = (".usda", ".usdc", ".usdz", ".usd", ".zip")
CHUNK = 1 << 20
_DEFAULTS = {name: f.default for name, f in RenderSettings.model_fields.items()}
# The user making the request (FastAPI runs require_user once per request, however often
# it is named). A job of another user is a 404 like a job that does not exist, so that
# job ids do not leak.
CurrentUser = Annotated[User, Depends(require_user)]


def _integrator_params_form(text: str) -> dict:
    """The integrator_params form field (a JSON object) as a dict; RenderSettings checks
    the names and values against the registry."""
    if not text.strip():
        return {}
    try:
        value = json.loads(text)
    except (ValueError, RecursionError) as exc:  # ValueError: bad JSON, or an over-long integer
        raise HTTPException(422, f"integrator_params is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise HTTPException(422, 'integrator_params must be a JSON object such as {"max_distance": 2}')
    return value


def _shutter_form(value: str) -> list[str] | None:
    """OPEN,CLOSE as two items for RenderSettings to check (it names the field)."""
    if not value.strip():
        return None
    parts = [p.strip() for p in value.split(",")]
    if len(parts) != 2:
        raise HTTPException(422, f"shutter must be OPEN,CLOSE (two time codes), not {value!r}")
    return parts


def upload_too_large(limit: int) -> HTTPException:
    return HTTPException(413, f"the upload is larger than the limit of {_size(limit)}")


@router.post("", status_code=201, response_model=JobCreated,
             responses={400: {"description": "not a USD file"},
                        409: {"description": "the manifest names files the farm lacks: upload them"},
                        413: {"description": "file too large"},
                        422: {"description": "invalid settings, or a scene the renderer rejects"},
                        429: {"description": "the server is inspecting as many scenes as it may; "
                                             "retry after Retry-After seconds"}})
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
    width: Annotated[int | None, Form(description="default: the scene's render settings, else 512")] = None,
    height: Annotated[int | None, Form(description="default: the scene's render settings, else 512")] = None,
    spp: Annotated[int, Form(description="samples per pixel")] = _DEFAULTS["spp"],
    seed: Annotated[int, Form()] = _DEFAULTS["seed"],
    max_depth: Annotated[int, Form(description="maximum path length")] = _DEFAULTS["max_depth"],
    tile_size: Annotated[int, Form(description="tile edge in pixels")] = _DEFAULTS["tile_size"],
    target_error: Annotated[float | None, Form(
        description="render to this relative noise (0.01 = 1 %) instead of a fixed spp")] = None,
    min_spp: Annotated[int, Form(description="first pass (noise-target mode)")] = _DEFAULTS["min_spp"],
    max_spp: Annotated[int, Form(description="most samples (noise-target mode)")] = _DEFAULTS["max_spp"],
    time_limit: Annotated[float | None, Form(
        description="seconds after start when no further passes begin (noise-target mode)")] = None,
    priority: Annotated[int, Form(ge=protocol.MIN_PRIORITY, le=protocol.MAX_PRIORITY,
                                  description="0-9; higher goes first")] = protocol.DEFAULT_PRIORITY,
    integrator: Annotated[str | None, Form(description="a name from the renderer's registry "
                                                       "(`tessera render --integrator help`) or auto; "
                                                       "default: the registry's first")] = None,
    auto_pilot: Annotated[str | None, Form(max_length=4096, description=(
        "what a client's `auto` pilot measured (JSON), when it chose the integrator before "
        "sending the job: logged and written to the image's tessera:auto"))] = None,
    max_attempts: Annotated[int, Form(ge=1, le=100, description=(
        "failed deliveries of one tile pass (errors, crashes, dead workers) before the job "
        "fails naming the tile"))] = protocol.DEFAULT_MAX_ATTEMPTS,
    default_light: Annotated[bool, Form(description="light a scene that has no light with the default "
                                                   "lighting (white dome + camera key light); false: "
                                                   "it renders black")] = True,
    subdivision_level: Annotated[int | None, Form(ge=0, le=6, description=(
        "how many times subdivision surfaces are refined, 0-6 (0: their control cage); "
        "default: the renderer's, 2"))] = None,
    camera: Annotated[str | None, Form(description=(
        "the path of the Camera prim to render through, e.g. /World/closeup (default: the "
        "RenderSettings' camera, else the first camera, else a three-quarter view)"))] = None,
    frame: Annotated[float | None, Form(description=(
        "the USD time code to render (default: the stage's startTimeCode, else the default "
        "time)"))] = None,
    frames: Annotated[str, Form(description=(
        "a frame range instead of one frame: 1-24, 1-24x2 (every second), 1,5,9 or a mix; one "
        "job per frame, and the returned id is the sequence's (GET /jobs/{id}, "
        "/jobs/{id}/frames/{frame}/image.exr; docs/farm.md)"))] = "",
    shutter: Annotated[str, Form(description=(
        "OPEN,CLOSE in time codes from the frame, replacing the camera's shutter:open/close "
        "(0,0: no motion blur; docs/motion.md); empty: the camera's"))] = "",
    variants: Annotated[str, Form(description=(
        "comma-separated variant selections, each /Prim/Path:set=value, in place of the stage's "
        "own (checked when a worker composes the stage: an unknown prim, set or variant fails "
        "the job naming the choices)"))] = "",
    aovs: Annotated[str, Form(description="comma-separated extra EXR layers: albedo, normal, depth, "
                                          "spp, variance, or all (docs/aovs.md)")] = "",
    denoise: Annotated[bool, Form(description="add a denoised layer (denoised.R/G/B) and "
                                              "/jobs/ID/denoised.png; adds the albedo and normal "
                                              "AOVs (docs/denoise.md)")] = False,
    integrator_params: Annotated[str, Form(description=(
        'the integrator\'s own settings as a JSON object of name -> number, e.g. '
        '{"max_distance": 2} for ao ("inf" as a string for infinity; docs/integrators.md)'))] = "",
    crop: Annotated[str, Form(description="x0,y0,x1,y1 (x1, y1 exclusive): the EXR holds only this "
                                          "region, as its data window inside the full frame "
                                          "(docs/aovs.md); empty: the whole image")] = "",
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
    frame_list = None
    if frames.strip():
        if frame is not None:
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
    params = dict(spp=spp, seed=seed, max_depth=max_depth, tile_size=tile_size, integrator=integrator,
                  target_error=target_error, min_spp=min_spp, max_spp=max_spp,
                  time_limit=time_limit, aovs=aovs, default_light=default_light, denoise=denoise,
                  integrator_params=_integrator_params_form(integrator_params),
                  subdivision_level=subdivision_level, camera=camera or None, frame=frame,
                  shutter=_shutter_form(shutter),
                  variants=[v.strip() for v in variants.split(",") if v.strip()] or None,
                  auto_pilot=auto_pilot or None)
    if crop.strip():
        params["crop"] = crop
    if integrator is None:
        del params["integrator"]  # RenderSettings' default: the registry's first
    if denoise:  # the merge here denoises: refuse now rather than deliver a job without it
        from tessera_base.denoise import unavailable_reason

        if (reason := unavailable_reason()) is not None:
            raise HTTPException(422, f"denoise: this server cannot denoise: {reason}")
    # Check what can be checked before the (slow) inspection; resolution comes later.
    _render_settings(width=width if width is not None else 1,
                     height=height if height is not None else 1,
                     **{k: v for k, v in params.items() if k != "crop"})  # the frame is not known yet

    with tempfile.TemporaryDirectory(prefix=f"tessera-upload-{os.getpid()}-") as tmp:
        path = Path(tmp, protocol.scene_file_name(suffix))
        scene_hash = (_save_upload(file, path, settings.max_upload_bytes) if packed is None
                      else _assemble(request, packed, path, settings.max_upload_bytes, user))
        try:
            info = _inspect(request, path, scene_hash, params["variants"] or (), user,
                            params.get("subdivision_level"))
        except HTTPException as exc:
            if packed is not None or suffix in (".zip", ".usdz") or exc.status_code != 422:
                raise
            raise HTTPException(422, _loose_layer_detail(str(exc.detail), path.name, name)) from None
        if params["camera"] is not None and info.cameras is not None and params["camera"] not in info.cameras:
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
    warnings = [*warnings, *integrators.scene_warnings(render.integrator, curve_segments=info.curve_segments)]
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


@router.get("", response_model=JobList, responses={403: {"description": "`user` names "
                                                                     "another user (admins only)"}})
def list_jobs(request: Request, user: CurrentUser,
              state: Annotated[JobState | None, Query(description="only jobs in this state")] = None,
              owner: Annotated[str | None, Query(alias="user", max_length=200, description=(
                  "only this user's jobs (an admin may name anyone; others only themselves)"))] = None,
              name: Annotated[str | None, Query(max_length=200, description=(
                  "only jobs whose scene name contains this (case-insensitive)"))] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 100,
              offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0) -> JobList:
    """Your jobs (an admin: everyone's), newest first, a page of `limit` from `offset`;
    `more` says whether another page follows."""
    store: JobStore = request.app.state.store
    if owner is not None and not user.admin and owner != user.name:
        raise HTTPException(403, "only an admin lists another user's jobs")
    if owner is None and not user.admin:
        owner = user.name
    found = store.list(state, limit + 1, offset, owner, name=name or None)
    return JobList(jobs=[_status(j.spec.job_id, j) for j in found[:limit]], offset=offset,
                   more=len(found) > limit)


@router.get("/{job_id}", response_model=JobStatus | SequenceStatus,
            responses={404: {"description": "no such job"}})
def get_job(job_id: str, request: Request, user: CurrentUser) -> JobStatus | SequenceStatus:
    """A job's status; for the id of a frame range, the sequence's (every frame's job with
    its state)."""
    if (record := _sequence(request, job_id, user)) is not None:
        return sequence_status(job_id, record)
    job = _job(request, job_id, user)
    if job.state == "done" and job.spec.settings.adaptive and job.reached_error is None:
        store: JobStore = request.app.state.store
        try:  # once per job: the tiles are merged as for the image, and the number kept
            value = reached_noise(job.spec, store.tiles(job_id), store.splats(job_id))
        except MergeError as e:
            logger.warning("job %s: cannot measure the noise reached: %s", job_id, e)
        else:
            store.remember_reached_error(job_id, value)
            job.reached_error = "none" if value is None else repr(value)
    return _status(job_id, job)


@router.delete("/{job_id}", response_model=JobStatus | SequenceStatus,
               responses={404: {"description": "no such job"}})
def cancel_job(job_id: str, request: Request, user: CurrentUser) -> JobStatus | SequenceStatus:
    """Cancels a queued, running or paused job: its open tiles are dropped at once and a
    tile being rendered is abandoned. A finished job is left as it is. For a frame range,
    every frame's job."""
    if (record := _sequence(request, job_id, user)) is not None:
        store: JobStore = request.app.state.store
        for _, frame_job, job in record["frames"]:
            if job is not None:
                store.cancel(frame_job)
        return sequence_status(job_id, _sequence(request, job_id, user) or record)
    _check_owner(request, job_id, user)
    store: JobStore = request.app.state.store
    if not store.cancel(job_id):
        raise _not_found(job_id)
    return _status(job_id, _job(request, job_id, user))


@router.post("/{job_id}/pause", response_model=JobStatus | SequenceStatus,
             responses={404: {"description": "no such job"}})
def pause_job(job_id: str, request: Request, user: CurrentUser) -> JobStatus | SequenceStatus:
    """Stops handing out the job's tiles (tiles being rendered are still stored). A job
    that is not queued or running is left as it is. For a frame range, every frame's job."""
    if (record := _sequence(request, job_id, user)) is not None:
        return for_each_frame(request, job_id, user, record, request.app.state.store.pause)
    _check_owner(request, job_id, user)
    if not request.app.state.store.pause(job_id):
        raise _not_found(job_id)
    return _status(job_id, _job(request, job_id, user))


@router.post("/{job_id}/resume", response_model=JobStatus | SequenceStatus,
             responses={404: {"description": "no such job"}})
def resume_job(job_id: str, request: Request, user: CurrentUser) -> JobStatus | SequenceStatus:
    """Resumes a paused job; any other job is left as it is. For a frame range, every
    paused frame."""
    if (record := _sequence(request, job_id, user)) is not None:
        return for_each_frame(request, job_id, user, record, request.app.state.store.resume)
    _check_owner(request, job_id, user)
    if not request.app.state.store.resume(job_id):
        raise _not_found(job_id)
    return _status(job_id, _job(request, job_id, user))


@router.get("/{job_id}/log", response_model=JobLog, responses={404: {"description": "no such job"}})
def get_log(job_id: str, request: Request, user: CurrentUser) -> JobLog:
    """The job's log: state changes, warnings, failed attempts, blocklisted workers. For a
    frame range, every frame's log in time order, each line naming its frame."""
    if (record := _sequence(request, job_id, user)) is not None:
        store: JobStore = request.app.state.store
        lines = [(line, f"frame {frame}") for frame, frame_job, job in record["frames"] if job is not None
                 for line in store.log(frame_job)]
        # Stored as '<unix time> <message>': sorted by the time, stable within a frame.
        lines.sort(key=lambda item: _log_time(item[0]))
        return JobLog(id=job_id, lines=[_iso_line(f"{stamp} {where}: {rest}") for line, where in lines
                                        for stamp, _, rest in [line.partition(" ")]])
    _job(request, job_id, user)
    return JobLog(id=job_id, lines=[_iso_line(line) for line in request.app.state.store.log(job_id)])


def _log_time(line: str) -> float:
    try:
        return float(line.split(" ", 1)[0])
    except ValueError:
        return 0.0


def _iso_line(line: str) -> str:
    """A stored log line, '<unix time> <message>', as people read it: the time in ISO 8601
    UTC to the millisecond ('2026-12-07T15:42:30.327+00:00 job queued ...')."""
    stamp, sep, rest = line.partition(" ")
    try:
        when = datetime.fromtimestamp(float(stamp), timezone.utc)
    except (ValueError, OverflowError, OSError):
        return line
    return when.isoformat(timespec="milliseconds") + sep + rest


def for_each_frame(request: Request, sequence_id: str, user: User, record: dict, change) -> SequenceStatus:
    """Applies a state change (store.pause, resume, ...) to every frame's job that still
    exists; frames it does not apply to (finished, say) are left as they are."""
    for _, frame_job, job in record["frames"]:
        if job is not None:
            change(frame_job)
    return sequence_status(sequence_id, _sequence(request, sequence_id, user) or record)


@router.get("/{job_id}/events", response_class=StreamingResponse,
            responses={200: {"content": {"text/event-stream": {}},
                             "description": "Server-Sent Events: `state`, `tile`, `pass`, "
                                            "`scene_pass` and `failure` events whose data is a "
                                            "JSON JobEvent; "
                                            "the stream ends after the job's final state"},
                       404: {"description": "no such job"}})
async def job_events(job_id: str, request: Request, user: CurrentUser,
                     after: Annotated[str | None, Query(
                         pattern=r"^\d+(-\d+)?$",
                         description="resume after this event id (or send Last-Event-ID)")] = None
                     ) -> StreamingResponse:
    # Async, on its own Redis client: a stream may stay open for hours, and must hold
    # neither a worker thread nor a pooled connection of the synchronous routes.
    _check_id(job_id)
    aredis = request.app.state.aredis
    if (record := await asyncio.to_thread(_sequence, request, job_id, user)) is not None:
        return _sequence_events(request, record)
    job_key, events_key = rdb.job_key(job_id), rdb.job_events_key(job_id)
    state, owner = await aredis.hmget(job_key, ["state", "owner"])
    if state is None or not user.may_see(owner.decode() if owner is not None else None):
        raise _not_found(job_id)
    if after is not None and not _is_stream_id(after):
        # Checked before the 200: Redis refuses an id beyond 64 bits only once the stream
        # has started, which cut it without a word.
        raise HTTPException(422, f"after={after[:40]!r} is not an event id: MILLISECONDS or "
                                 f"MILLISECONDS-SEQUENCE, each at most {_U64_MAX}")
    cursor = after or request.headers.get("last-event-id") or "0"
    if not _is_stream_id(cursor):  # a browser's reconnection header: start over instead
        cursor = "0"

    async def stream():
        nonlocal cursor
        idle = 0
        while not await request.is_disconnected():
            reply = await aredis.xread({events_key: cursor}, count=100, block=1000)
            events = reply[0][1] if reply else []
            for event_id, raw in events:
                cursor = event_id.decode()
                try:
                    event = rdb.JobEvent.from_fields(raw)
                except ValidationError:
                    continue  # not an event of ours: never break the stream over it
                yield (f"id: {cursor}\nevent: {event.type}\n"
                       f"data: {json.dumps(event.model_dump(exclude_none=True))}\n\n")
                if event.type == "state" and event.state in FINAL_STATES:
                    return
            if not events:
                idle += 1
                state = await aredis.hget(job_key, "state")
                if state is None or (state.decode() in FINAL_STATES and idle > 1):
                    return  # expired, or final with its last event already sent
                if idle % 15 == 0:
                    yield ": keep-alive\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


def _sequence_events(request: Request, record: dict) -> StreamingResponse:
    """A frame range's events: every frame's, merged as they come, each event's data
    naming its `frame`; the stream ends once every frame is final. (Resuming after an event
    id is for single jobs: a merged stream has one cursor per frame.)"""
    aredis = request.app.state.aredis
    frames = {rdb.job_events_key(frame_job): (frame, rdb.job_key(frame_job))
              for frame, frame_job, job in record["frames"] if job is not None}

    async def stream():
        cursors = {key: "0" for key in frames}
        finished: set[str] = set()
        idle = 0
        while cursors and not await request.is_disconnected():
            reply = await aredis.xread(cursors, count=100, block=1000)
            for key, events in reply or []:
                key = key.decode() if isinstance(key, bytes) else key
                frame, _ = frames[key]
                for event_id, raw in events:
                    cursors[key] = event_id.decode()
                    try:
                        event = rdb.JobEvent.from_fields(raw)
                    except ValidationError:
                        continue
                    data = {**event.model_dump(exclude_none=True), "frame": frame}
                    yield f"event: {event.type}\ndata: {json.dumps(data)}\n\n"
                    if event.type == "state" and event.state in FINAL_STATES:
                        finished.add(key)
            for key in finished:
                cursors.pop(key, None)
            finished.clear()
            if not reply:
                idle += 1
                for key in list(cursors):  # expired, or final with its last event already sent
                    state = await aredis.hget(frames[key][1], "state")
                    if state is None or (state.decode() in FINAL_STATES and idle > 1):
                        cursors.pop(key)
                if idle % 15 == 0:
                    yield ": keep-alive\n\n"

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


@router.get("/{job_id}/image.exr", response_class=Response,
            responses={200: {"content": {"image/x-exr": {}}}, 404: {}, 409: {"description": "not done"}})
def get_image(job_id: str, request: Request, user: CurrentUser) -> Response:
    """The rendered image: float linear RGBA OpenEXR."""
    data = _image(request, job_id, "exr", user)
    return Response(data, media_type="image/x-exr",
                    headers={"Content-Disposition": f'attachment; filename="{job_id}.exr"'})


@router.get("/{job_id}/preview.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 404: {},
                       409: {"description": "failed or cancelled"}})
def get_preview(job_id: str, request: Request, user: CurrentUser) -> Response:
    """A tonemapped 8-bit sRGB preview: of the finished image, or while the job is queued,
    running or paused, of what is rendered so far (missing tiles are black)."""
    job = _job(request, job_id, user)
    if job.state in ("queued", "running", "paused"):
        try:
            store = request.app.state.store
            rgba = merge_tiles(job.spec, store.tiles(job_id), partial=True,
                               splats=store.splats(job_id))
        except MergeError as e:
            raise HTTPException(500, f"cannot assemble the preview of job {job_id}: {e}") from None
        data = encode_image(rgba, job.spec, "png")
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})
    data = _image(request, job_id, "png", user)
    return Response(data, media_type="image/png",
                    headers={"Content-Disposition": f'inline; filename="{job_id}.png"'})


@router.get("/{job_id}/denoised.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 404: {},
                       409: {"description": "not denoised, failed or cancelled"}})
def get_denoised_preview(job_id: str, request: Request, user: CurrentUser) -> Response:
    """The denoised image (docs/denoise.md) as a tonemapped sRGB PNG, of a job submitted
    with denoise=true: while it runs, of what is rendered so far; once done, of the EXR's
    denoised layer."""
    job = _job(request, job_id, user)
    if not job.spec.settings.denoise:
        raise HTTPException(409, f"job {job_id} was not submitted with denoise=true")
    if job.state in ("queued", "running", "paused"):
        store = request.app.state.store
        try:
            _, aovs = merge_tiles(job.spec, store.tiles(job_id), partial=True, with_aovs=True,
                                  splats=store.splats(job_id))
            data = denoised_png(aovs, job.spec)
        except MergeError as e:
            raise HTTPException(409, f"no denoised preview of job {job_id}: {e}") from None
        return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})
    layer = read_denoised(_image(request, job_id, "exr", user))
    if layer is None:
        raise HTTPException(409, f"job {job_id} has no denoised layer (the server's log says why)")
    return Response(encode_image(layer, job.spec, "png"), media_type="image/png",
                    headers={"Content-Disposition": f'inline; filename="{job_id}.denoised.png"'})


@router.get("/{job_id}/frames/{frame}/image.exr", response_class=Response,
            responses={200: {"content": {"image/x-exr": {}}}, 404: {}, 409: {"description": "not done"}})
def get_frame_image(job_id: str, frame: int, request: Request, user: CurrentUser) -> Response:
    """One frame of a frame range: its float linear RGBA OpenEXR."""
    frame_job = _frame_job(request, job_id, frame, user)
    return Response(_image(request, frame_job, "exr", user), media_type="image/x-exr",
                    headers={"Content-Disposition": f'attachment; filename="{job_id}.{frame:04d}.exr"'})


@router.get("/{job_id}/frames/{frame}/preview.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 404: {}, 409: {"description": "not done"}})
def get_frame_preview(job_id: str, frame: int, request: Request, user: CurrentUser) -> Response:
    """One frame of a frame range: its tonemapped sRGB PNG (of what is rendered so far
    while it runs, as /jobs/{id}/preview.png)."""
    return get_preview(_frame_job(request, job_id, frame, user), request, user)


# ---------------------------------------------------------------------------- helpers
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


def _sequence(request: Request, sequence_id: str, user: User) -> dict | None:
    """The frame range with this id that `user` may see, else None."""
    _check_id(sequence_id)
    record = request.app.state.store.sequence(sequence_id)
    if record is None or not user.may_see(record["owner"]):
        return None
    return record


def _frame_job(request: Request, sequence_id: str, frame: int, user: User) -> str:
    record = _sequence(request, sequence_id, user)
    if record is None:
        raise HTTPException(404, f"no frame range with id {sequence_id!r}")
    for f, job_id, _ in record["frames"]:
        if f == frame:
            return job_id
    raise HTTPException(404, f"frame {frame} is not one of the frames of {sequence_id} "
                             f"({', '.join(str(f) for f, _, _ in record['frames'][:20])}"
                             f"{', ...' if len(record['frames']) > 20 else ''})")


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
             subdivision_level: int | None = None) -> SceneInfo:
    """The scene's pre-flight, composed with the job's variant selections and translated at
    its subdivision level (a level above the default multiplies what subdivision surfaces
    cost): remembered (passed or refused) for this exact file, selection and level, else
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
    info = _inspect_limited(request, path, scene_hash, variants, max_triangles, limits, why, subdivision_level)
    if info.translated_bytes > user_translated:
        raise HTTPException(422, f"the scene cannot be rendered: it translates to "
                                 f"{_size(info.translated_bytes)}, more than the "
                                 f"{_size(user_translated)} a scene of yours may "
                                 f"(TESSERA_USER_MAX_TRANSLATED_BYTES or TESSERA_USER_LIMITS)")
    return info


def _inspect_limited(request: Request, path: Path, scene_hash: str, variants: Sequence[str],
                     max_triangles: int, limits: str, why: str, subdivision_level: int | None = None) -> SceneInfo:
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
                                         subdivision_level=subdivision_level)
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


def _check_id(job_id: str) -> None:
    """A string that is not a job id names no job: 404, before any Redis key is built."""
    if not protocol.is_job_id(job_id):
        raise _not_found(job_id)


def _job(request: Request, job_id: str, user: User) -> Job:
    _check_id(job_id)
    job = request.app.state.store.get(job_id)
    if job is None or not user.may_see(job.owner):
        raise _not_found(job_id)
    return job


def _check_owner(request: Request, job_id: str, user: User) -> None:
    """404 unless the job exists and `user` may see it (before anything changes it)."""
    _check_id(job_id)
    store: JobStore = request.app.state.store
    if user.admin:
        return  # the state change itself says whether the job exists
    if not user.may_see(store.owner(job_id)):
        raise _not_found(job_id)


def _not_found(job_id: str) -> HTTPException:
    return HTTPException(404, f"no job with id {job_id!r}")


def _image(request: Request, job_id: str, fmt: str, user: User) -> bytes:
    store: JobStore = request.app.state.store
    job = _job(request, job_id, user)
    if job.state != "done":
        detail = f"job {job_id} is {job.state}; its image is available once it is done"
        if job.error:
            detail += f" (error: {job.error})"
        raise HTTPException(409, detail)
    data = store.cached_image(job_id, fmt)
    if data is None:
        try:
            rgba, aovs = merge_tiles(job.spec, store.tiles(job_id), with_aovs=True,
                                     splats=store.splats(job_id))
        except MergeError as e:
            raise HTTPException(500, f"cannot assemble the image of job {job_id}: {e}") from None
        if aovs.denoise_warning:
            logger.warning("job %s: %s", job_id, aovs.denoise_warning)
        black = black_image_warning(protocol.in_crop(job.spec.settings, rgba), job.brightest_light)
        if black and store.add_warning(job_id, black):
            logger.warning("job %s: %s", job_id, black)
        data = encode_image(rgba, job.spec, fmt, aovs=aovs)
        store.cache_image(job_id, fmt, data)
    return data


def _status(job_id: str, job: Job) -> JobStatus:
    def when(t: float | None) -> datetime | None:
        return datetime.fromtimestamp(t, timezone.utc) if t is not None else None

    end = job.finished_at if job.finished_at is not None else time.time()
    return JobStatus(
        id=job_id, state=job.state, scene_name=job.spec.scene_name, settings=job.spec.settings,
        priority=job.spec.priority, tiles_done=job.tiles_done, tiles_total=job.tiles_total,
        passes_done=job.passes_done,
        created_at=when(job.created_at), started_at=when(job.started_at),
        finished_at=when(job.finished_at),
        elapsed_seconds=round(max(0.0, end - job.created_at), 3),
        render_seconds=round(job.render_seconds, 3),
        warnings=job.warnings, error=job.error, owner=job.owner, sequence=job.sequence,
        **_noise_reached(job))


def _noise_reached(job: Job) -> dict:
    """reached_error and target_reached of a done noise-target job whose noise was measured."""
    if not job.reached_error or job.reached_error == "none" or job.spec.settings.target_error is None:
        return {}
    value = float(job.reached_error)
    return {"reached_error": value, "target_reached": value <= job.spec.settings.target_error}


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


_EVENT_ID = re.compile(r"^\d+(-\d+)?$")
_U64_MAX = (1 << 64) - 1


def _is_stream_id(text: str) -> bool:
    """A Redis stream id XREAD accepts: one or two unsigned 64-bit numbers."""
    # (The length first: int() refuses more than 4,300 digits with an error of its own.)
    return bool(_EVENT_ID.match(text)) and all(len(part) <= 20 and int(part) <= _U64_MAX
                                               for part in text.split("-"))


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
