"""/workers and /metrics: the state of the farm as a whole."""
from __future__ import annotations

from datetime import datetime, timezone

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

from tessera_base import protocol

from ..auth import require_user
from ..schemas import WorkerList, WorkerStatus
from ..store import JobStore
from ..users import User

router = APIRouter(tags=["farm"])


@router.get("/workers", response_model=WorkerList)
def list_workers(request: Request, user: Annotated[User, Depends(require_user)]) -> WorkerList:
    """Live workers (those whose heartbeat has not expired). What a worker is rendering is
    shown only for your own jobs (an admin: for every job)."""
    store: JobStore = request.app.state.store

    def when(t: float) -> datetime:
        return datetime.fromtimestamp(t, timezone.utc)

    def current(task: str) -> str | None:
        if not task:
            return None
        job_id = task.split("/", 1)[0]
        if user.admin or (protocol.is_job_id(job_id) and user.may_see(store.owner(job_id))):
            return task
        return "another user's job"

    return WorkerList(workers=[
        WorkerStatus(name=w.name, host=w.host, pid=w.pid, started_at=when(w.started_at),
                     last_heartbeat=when(w.beat_at), current=current(w.current),
                     tiles_done=w.tiles_done, failures=w.failures, disabled=w.disabled)
        for w in store.workers()])


class FarmCollector:
    """Reads the farm's counters from Redis at scrape time, so that every API process
    reports the same numbers (the counters live in Redis, written by the workers)."""

    def __init__(self, store: JobStore, pool=None):
        self.store, self.pool = store, pool

    def collect(self):
        depth = GaugeMetricFamily("tessera_queue_depth",
                                  "Open tile passes (queued or rendering) per job priority",
                                  labels=["priority"])
        for priority, n in sorted(self.store.queue_depths().items()):
            depth.add_metric([str(priority)], n)
        yield depth
        stats = self.store.stats()
        for name, key, doc in (
                ("tessera_tiles", "tiles", "Tiles finished (all passes stored)"),
                ("tessera_passes", "passes", "Tile passes stored"),
                ("tessera_render_seconds", "render_seconds", "Seconds spent rendering stored passes"),
                ("tessera_tile_failures", "failures", "Failed render attempts"),
                ("tessera_tiles_poisoned", "poisoned", "Tiles that failed too often (job failed)"),
                ("tessera_tiles_reclaimed", "reclaimed", "Tiles taken over from dead workers")):
            yield CounterMetricFamily(name, doc, value=stats.get(key, 0.0))
        for name, key, doc in (
                ("tessera_preflight_inspections", "inspections", "Scene inspections run (uploads "
                                                                 "of a file seen before are not inspected)"),
                ("tessera_preflight_rejections", "inspections_rejected", "Scene inspections that "
                                                                         "refused the scene"),
                ("tessera_scene_translations", "scene_translations", "Scenes translated by workers "
                                                                     "(once per scene and variant)"),
                ("tessera_data_sweeps", "data_sweeps", "Sweeps of the data directory"),
                ("tessera_data_evicted", "data_evicted", "Data store files deleted by sweeps (nothing "
                                                         "held them)"),
                ("tessera_data_evicted_bytes", "data_evicted_bytes", "Bytes of those files")):
            yield CounterMetricFamily(name, doc, value=stats.get(key, 0.0))
        if self.pool is not None:  # this API process's pool
            yield GaugeMetricFamily("tessera_preflight_running", "Scene inspections running in "
                                    "this API process", value=self.pool.running)
            yield GaugeMetricFamily("tessera_preflight_waiting", "Uploads waiting for an "
                                    "inspection slot in this API process", value=self.pool.waiting)
        workers = self.store.workers()
        yield GaugeMetricFamily("tessera_workers", "Live workers", value=len(workers))
        yield GaugeMetricFamily("tessera_workers_busy", "Workers rendering a tile",
                                value=sum(1 for w in workers if w.current))


@router.get("/metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}},
                             "description": "Prometheus text exposition format"}})
def metrics(request: Request) -> Response:
    registry = CollectorRegistry(auto_describe=False)
    registry.register(FarmCollector(request.app.state.store, request.app.state.inspections))
    return Response(generate_latest(registry), media_type=CONTENT_TYPE_LATEST)
