"""What the monitor page does to jobs beyond pause, resume, cancel and priority: retry a
failed or cancelled job (or every such frame of a frame range), and delete a finished one
with everything it keeps."""
from __future__ import annotations

import uuid

from fastapi import APIRouter, HTTPException, Request, Response

from ..schemas import FrameJob, JobCreated
from ..store import Job, JobStore
from .jobs import CurrentUser, _job, _sequence

router = APIRouter(prefix="/jobs", tags=["jobs"])
RETRYABLE = ("failed", "cancelled")


def _retry(store: JobStore, job_id: str, job: Job) -> str:
    """A new job with the failed one's scene, settings, priority, owner and frame range;
    the old one stays as it was (its log names the new one)."""
    if job.state not in RETRYABLE:
        raise HTTPException(409, f"job {job_id} is {job.state}: only a failed or cancelled job is retried")
    if not store.touch_scene(job.spec.scene_hash):
        raise HTTPException(409, f"the scene of job {job_id} ({job.spec.scene_name}) is no longer "
                                 f"stored (its retention ran out): submit it again")
    spec = job.spec.model_copy(update={"job_id": uuid.uuid4().hex})
    store.create_job(spec, job.warnings, owner=job.owner, brightest_light=job.brightest_light,
                     sequence=job.sequence, note=f"retry of job {job_id}")
    store.add_log(job_id, f"retried as job {spec.job_id}")
    if job.sequence is not None:
        store.replace_frame(job.sequence, job_id, spec.job_id)
    return spec.job_id


@router.post("/{job_id}/retry", status_code=201, response_model=JobCreated,
             responses={404: {"description": "no such job"},
                        409: {"description": "not failed or cancelled, or its scene expired"}})
def retry_job(job_id: str, request: Request, response: Response, user: CurrentUser) -> JobCreated:
    """Submits a failed or cancelled job again, as a new job (new id, the same scene and
    settings, priority and owner; a frame of a frame range takes its place in the range).
    For a frame range's id: every failed or cancelled frame (409 if none is)."""
    store: JobStore = request.app.state.store
    if (record := _sequence(request, job_id, user)) is not None:
        frames = [(f, fj, j) for f, fj, j in record["frames"] if j is not None and j.state in RETRYABLE]
        if not frames:
            raise HTTPException(409, f"no frame of {job_id} failed or was cancelled")
        retried = [FrameJob(frame=f, job=_retry(store, fj, j)) for f, fj, j in frames]
        s = frames[0][2].spec
        response.headers["Location"] = f"/jobs/{job_id}"
        return JobCreated(id=job_id, state="queued", tiles_total=sum(j.tiles_total for _, _, j in frames),
                          width=s.settings.width, height=s.settings.height, priority=s.priority,
                          warnings=record["warnings"], frames=retried)
    job = _job(request, job_id, user)
    new_id = _retry(store, job_id, job)
    response.headers["Location"] = f"/jobs/{new_id}"
    return JobCreated(id=new_id, state="queued", tiles_total=job.tiles_total,
                      width=job.spec.settings.width, height=job.spec.settings.height,
                      priority=job.spec.priority, warnings=job.warnings)


@router.post("/{job_id}/purge", status_code=204, response_class=Response,
             responses={404: {"description": "no such job"},
                        409: {"description": "not finished: cancel it first"}})
def purge_job(job_id: str, request: Request, user: CurrentUser) -> Response:
    """Deletes a finished (done, failed or cancelled) job now, with its tiles, image,
    events and log, instead of at the end of its retention. A job that is not finished
    is a 409 (DELETE /jobs/{id} cancels it). For a frame range's id: every frame, all
    finished, and the range itself."""
    store: JobStore = request.app.state.store
    if (record := _sequence(request, job_id, user)) is not None:
        running = [str(f) for f, _, j in record["frames"] if j is not None and not j.final]
        if running:
            raise HTTPException(409, f"frames {', '.join(running)} of {job_id} are not finished: cancel them first")
        for _, frame_job, job in record["frames"]:
            if job is not None:
                store.purge(frame_job, job.owner)
        store.forget_sequence(job_id)
        return Response(status_code=204)
    job = _job(request, job_id, user)
    if not job.final:
        raise HTTPException(409, f"job {job_id} is {job.state}: cancel it first (DELETE /jobs/{job_id})")
    store.purge(job_id, job.owner)
    return Response(status_code=204)
