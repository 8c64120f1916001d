"""HTTP request/response models. The job and tile schema itself is tessera_base.protocol."""
from __future__ import annotations

from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from tessera_base.protocol import JobState, RenderSettings


class FrameJob(BaseModel):
    frame: int
    job: str = Field(description="the frame's own job id (every /jobs/{id} route takes it)")


class JobCreated(BaseModel):
    id: str
    state: JobState
    tiles_total: int
    width: int
    height: int
    priority: int
    warnings: list[str] = Field(description="what the renderer will ignore or approximate")
    frames: list[FrameJob] | None = Field(
        default=None, description="for a frame range: each frame's job; `id` is then the "
                                  "sequence's (GET /jobs/{id}, DELETE /jobs/{id}, "
                                  "/jobs/{id}/frames/{frame}/image.exr)")


class FrameStatus(BaseModel):
    frame: int
    job: str
    state: JobState | Literal["expired"] = Field(description="the frame job's state; expired once "
                                                             "its retention has removed it")
    tiles_done: int = 0
    tiles_total: int = 0
    error: str | None = None


class SequenceStatus(BaseModel):
    """A frame range: one job per frame, its state the frames' together (running while any
    runs; done when all are; failed, cancelled or paused when a frame is and none is still
    to render)."""

    id: str
    kind: Literal["sequence"] = "sequence"
    state: JobState
    scene_name: str
    frames: list[FrameStatus]
    tiles_done: int
    tiles_total: int
    created_at: datetime
    warnings: list[str]
    owner: str | None = None


class JobStatus(BaseModel):
    id: str
    state: JobState
    scene_name: str
    settings: RenderSettings
    priority: int = Field(description="0 (lowest) to 9; higher-priority jobs' tiles go first")
    tiles_done: int = Field(description="tiles whose last pass is stored")
    tiles_total: int
    passes_done: int = Field(description="tile passes stored (one per tile in fixed-spp mode)")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    elapsed_seconds: float = Field(description="from submission until finished (or now)")
    render_seconds: float = Field(description="sum of the render times of the stored passes")
    warnings: list[str]
    error: str | None = None
    owner: str | None = Field(default=None, description="the user who submitted the job")
    sequence: str | None = Field(default=None, description="the frame range this job is a frame "
                                                           "of (its frame: settings.frame)")
    reached_error: float | None = Field(
        default=None, description="a done noise-target job (GET /jobs/{id}): the relative noise its "
                                  "image reached, measured as the EXR's tessera:reached_error; null "
                                  "otherwise, or when the image has no noise estimate")
    target_reached: bool | None = Field(
        default=None, description="whether reached_error is within settings.target_error (false: "
                                  "max_spp or time_limit stopped the job first); null when not known")


class JobList(BaseModel):
    jobs: list[JobStatus]
    offset: int = Field(default=0, description="the page's first job's place in the filtered list")
    more: bool = Field(default=False, description="whether jobs follow this page (ask with "
                                                  "offset + limit)")


class JobLog(BaseModel):
    id: str
    lines: list[str] = Field(description="'<ISO 8601 UTC time> <message>', oldest first, e.g. "
                                         "'2026-12-07T15:42:30.327+00:00 job queued ...'")


class WorkerStatus(BaseModel):
    name: str
    host: str
    pid: int
    started_at: datetime
    last_heartbeat: datetime
    current: str | None = Field(description="'job/tile/pass' being rendered, if any")
    tiles_done: int = Field(description="tile passes this worker stored")
    failures: int = Field(description="failed render attempts on this worker")
    disabled: bool = Field(default=False, description="an admin disabled it: it takes no new task")


class WorkerList(BaseModel):
    workers: list[WorkerStatus]


class Health(BaseModel):
    status: str = Field(description="ok; degraded (the API works but the farm does not render: "
                                    "see problems); or redis unreachable")
    redis: bool
    workers: int = Field(default=0, description="workers whose heartbeat is current")
    problems: list[str] = Field(default_factory=list)


class Problem(BaseModel):
    detail: str


TaskState = Literal["queued", "rendering", "done", "failed", "waiting", "abandoned"]


class TaskStatus(BaseModel):
    """One tile of a job (all its passes together), or one scene pass (an iteration's
    scene-wide task of an integrator with scene passes)."""

    kind: Literal["tile", "scene_pass"]
    index: int = Field(description="the tile's index in the grid (row-major), or the scene "
                                   "pass's iteration")
    x0: int | None = Field(default=None, description="a tile's rectangle in pixels")
    y0: int | None = None
    width: int | None = None
    height: int | None = None
    state: TaskState = Field(description="queued; rendering (a worker holds it); done; failed "
                                         "(its attempts ran out: the job failed); waiting (for "
                                         "its next pass to be queued, by a pass barrier or a "
                                         "scene pass); abandoned (the job ended without it)")
    pass_index: int | None = Field(default=None, description="the newest pass stored, queued "
                                                             "or being rendered")
    passes_done: int = Field(default=0, description="passes stored")
    samples: int | None = Field(default=None, description="samples per pixel stored so far")
    worker: str | None = Field(default=None, description="the worker rendering it, else the "
                                                         "last one that stored or failed it")
    attempts: int = Field(default=0, description="failed attempts, all passes together")
    last_error: str | None = None
    render_seconds: float = Field(default=0.0, description="render time of the stored passes")
    rendering_seconds: float | None = Field(default=None, description="while rendering: "
                                                                      "seconds since it was handed out")
    finished_at: datetime | None = Field(default=None, description="when its last stored pass "
                                                                   "was stored")
    slow: bool = Field(default=False, description="its seconds per pass (or, rendering, its "
                                                  "time so far) exceed slow_factor x the job's "
                                                  "median seconds per pass, and the median by "
                                                  "slow_min_excess")


class JobTasks(BaseModel):
    id: str
    state: JobState
    tiles: list[TaskStatus]
    scene_passes: list[TaskStatus]
    median_pass_seconds: float | None = Field(
        description="the median render time of the job's stored tile passes (null: none yet)")
    slow_factor: float
    slow_min_excess: float = Field(description="seconds a slow tile's time also exceeds the "
                                               "median by")
    events_complete: bool = Field(description="false when the job's event stream was trimmed "
                                              "(redis_schema.EVENTS_MAXLEN): older passes' workers "
                                              "and times are then missing")


class BlocklistCleared(BaseModel):
    worker: str
    jobs: list[str] = Field(description="the jobs not yet final that had blocklisted the worker")
