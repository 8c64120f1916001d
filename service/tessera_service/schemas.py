"""HTTP request/response models. The job and tile schema itself is tessera.protocol."""
from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, Field

from tessera.protocol import JobState, RenderSettings


class JobCreated(BaseModel):
    id: str
    state: JobState
    tiles_total: int
    width: int
    height: int
    warnings: list[str] = Field(description="what the renderer will ignore or approximate")


class JobStatus(BaseModel):
    id: str
    state: JobState
    scene_name: str
    settings: RenderSettings
    tiles_done: int
    tiles_total: int
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    elapsed_seconds: float = Field(description="from submission until finished (or now)")
    render_seconds: float = Field(description="sum of the render times of the finished tiles")
    warnings: list[str]
    error: str | None = None


class Health(BaseModel):
    status: str
    redis: bool
