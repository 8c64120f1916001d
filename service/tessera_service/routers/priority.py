"""POST /jobs/{id}/priority: change a job's priority after submission (the monitor page's
priority control; any API client may use it)."""
from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from tessera_base import protocol

from ..schemas import JobStatus, SequenceStatus
from .jobs import CurrentUser, _check_owner, _job, _not_found, _sequence, _status, for_each_frame

router = APIRouter(prefix="/jobs", tags=["jobs"])


class PriorityChange(BaseModel):
    priority: int = Field(ge=protocol.MIN_PRIORITY, le=protocol.MAX_PRIORITY,
                          description="0-9; higher goes first")


@router.post("/{job_id}/priority", response_model=JobStatus | SequenceStatus,
             responses={404: {"description": "no such job"}})
def set_priority(job_id: str, change: PriorityChange, request: Request,
                 user: CurrentUser) -> JobStatus | SequenceStatus:
    """Changes the priority of a queued, running or paused job: its remaining tiles are
    scheduled in the new priority's band (docs/farm.md, "Scheduling"). A finished job is
    left as it is. For a frame range, every frame's job."""
    if (record := _sequence(request, job_id, user)) is not None:
        store = request.app.state.store
        return for_each_frame(request, job_id, user, record, lambda job: store.set_priority(job, change.priority))
    _check_owner(request, job_id, user)
    if not request.app.state.store.set_priority(job_id, change.priority):
        raise _not_found(job_id)
    return _status(job_id, _job(request, job_id, user))
