"""/jobs: follow a job or a frame range (status, events, log, preview), download the
image, cancel, pause, resume. Submitting one is routers/submit.py's."""
from __future__ import annotations

import asyncio
import json
import logging
import re
import time
from datetime import datetime, timezone
from typing import Annotated

from fastapi import APIRouter, Depends, HTTPException, Query, Request, Response
from fastapi.responses import StreamingResponse
from pydantic import ValidationError

from tessera_base import protocol
from tessera_queue import redis_schema as rdb
from tessera_base.film import black_image_warning
from tessera_base.protocol import FINAL_STATES, JobState

from ..auth import require_user
from ..merge import MergeError, denoised_png, encode_image, merge_tiles, read_denoised, reached_noise
from ..schemas import JobList, JobLog, JobStatus, SequenceStatus
from ..sequences import sequence_status
from ..store import Job, JobStore
from ..users import User

router = APIRouter(prefix="/jobs", tags=["jobs"])
logger = logging.getLogger(__name__)

# The user making the request (FastAPI runs require_user once per request, however often
# it is named). A job of another user is a 404 like a job that does not exist, so that
# job ids do not leak.
CurrentUser = Annotated[User, Depends(require_user)]


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


_EVENT_ID = re.compile(r"^\d+(-\d+)?$")
_U64_MAX = (1 << 64) - 1


def _is_stream_id(text: str) -> bool:
    """A Redis stream id XREAD accepts: one or two unsigned 64-bit numbers."""
    # (The length first: int() refuses more than 4,300 digits with an error of its own.)
    return bool(_EVENT_ID.match(text)) and all(len(part) <= 20 and int(part) <= _U64_MAX
                                               for part in text.split("-"))


