"""/scaling: the one number an autoscaler needs, the farm's open work.

Every job has a Redis stream of its own (redis_schema.job_queue_key), so a scaler that
watches one named stream, such as KEDA's redis-streams scaler, cannot see the farm's
queue. This endpoint sums it instead, for KEDA's metrics-api scaler
(deploy/k8s/worker-scaledobject.yaml) or anything else that polls JSON. Like /metrics it
says nothing about whose jobs these are."""
from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from tessera_queue import redis_schema as rdb

router = APIRouter(tags=["farm"])

# Jobs whose queued tasks a worker may take now; a paused job's wait for a resume.
RUNNABLE_STATES = ("queued", "running")


class ScalingSignal(BaseModel):
    open_tasks: int = Field(description="tile passes and scene tasks of queued and running "
                                        "jobs that are waiting or being rendered")
    workers: int = Field(description="live workers (current heartbeat)")


@router.get("/scaling", response_model=ScalingSignal)
def scaling(request: Request) -> ScalingSignal:
    """Open work for an autoscaler: 0 means no worker is needed. A task being rendered
    counts until it is stored, so that busy workers are not scaled away."""
    store = request.app.state.store
    client = store.redis
    ids = [j.decode() for j in client.smembers(rdb.ACTIVE)]
    with client.pipeline(transaction=False) as pipe:
        for job_id in ids:
            pipe.hget(rdb.job_key(job_id), "state")
            pipe.xlen(rdb.job_queue_key(job_id))
        rows = pipe.execute()
    open_tasks = sum(int(length) for state, length in zip(rows[::2], rows[1::2])
                     if state is not None and state.decode() in RUNNABLE_STATES)
    return ScalingSignal(open_tasks=open_tasks, workers=len(store.workers()))
