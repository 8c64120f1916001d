"""GET /jobs/{id}/tasks: a job's tiles and scene passes with their state, worker,
attempts and times (the monitor page's task table; tasks_view says where each comes from)."""
from __future__ import annotations

from fastapi import APIRouter, Request

from ..schemas import JobTasks
from ..store import JobStore
from ..tasks_view import job_tasks
from .jobs import CurrentUser, _job

router = APIRouter(prefix="/jobs", tags=["jobs"])


@router.get("/{job_id}/tasks", response_model=JobTasks,
            responses={404: {"description": "no such job (or another user's)"}})
def get_tasks(job_id: str, request: Request, user: CurrentUser) -> JobTasks:
    """One row per tile (all its passes together) and per scene pass: queued, rendering
    (on which worker, for how long), done, failed or waiting; its failed attempts and last
    error, its passes, samples and render seconds, and whether it is slow (its seconds per
    pass above slow_factor x the job's median, and above the median by slow_min_excess). For a frame range, ask for a frame's job."""
    job = _job(request, job_id, user)
    store: JobStore = request.app.state.store
    return job_tasks(job_id, job, store.task_sources(job_id))
