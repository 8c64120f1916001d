"""The queue's task messages: one stream entry per tile pass, lockstep barrier or
scene-wide task (TileTask), and the tasks a job starts with."""
from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from tessera_base import integrators
from tessera_base.protocol import (DEFAULT_MAX_ATTEMPTS, DEFAULT_PRIORITY, MAX_PRIORITY, MIN_PRIORITY, SCHEMA_VERSION, JobSpec,
                                   RenderSettings, TileRect, job_tiles)


class TileTask(BaseModel):
    """One stream message: everything a worker needs to render one pass of one tile."""

    schema_version: Literal[2] = SCHEMA_VERSION
    job_id: str
    scene_hash: str
    scene_name: str
    settings: RenderSettings
    tile: TileRect
    pass_index: int = Field(default=0, ge=0)
    priority: int = Field(default=DEFAULT_PRIORITY, ge=MIN_PRIORITY, le=MAX_PRIORITY)
    max_attempts: int = Field(default=DEFAULT_MAX_ATTEMPTS, ge=1, le=100)
    # A pass barrier of a lockstep job (RenderSettings.lockstep), queued once every tile's
    # pass `pass_index` is stored: whoever takes it decides whether the image needs pass
    # pass_index + 1 and queues it for every tile, or finishes the job. `tile` is unused.
    decide: bool = False
    # A scene-wide task (an integrator with scene_passes): iteration pass_index's scene
    # pass. Whoever takes it computes the product (tessera_base.film.run_scene_pass), stores it
    # once and queues that iteration's tile passes. `tile` is unused.
    scene_pass: bool = False

    @property
    def field(self) -> str:
        from tessera_queue.redis_schema import result_field, scene_task_field
        if self.scene_pass:
            return scene_task_field(self.pass_index)
        return result_field(self.tile.index, self.pass_index)

    def to_fields(self) -> dict[str, str]:
        return {"task": self.model_dump_json()}

    @classmethod
    def from_fields(cls, fields: dict) -> "TileTask":
        raw = fields.get(b"task", fields.get("task"))
        if raw is None:
            raise ValueError("stream entry has no 'task' field")
        return cls.model_validate_json(raw)

    def next_pass(self) -> "TileTask":
        return self.model_copy(update={"pass_index": self.pass_index + 1})


    def decide_task(self) -> "TileTask":
        """The barrier that follows this lockstep pass."""
        return self.model_copy(update={"decide": True})

    def pass_tasks(self, pass_index: int) -> list["TileTask"]:
        """Pass `pass_index` of every tile of this task's job."""
        s = self.settings
        return [self.model_copy(update={"tile": rect, "pass_index": pass_index, "decide": False,
                                        "scene_pass": False})
                for rect in job_tiles(s)]

    def iteration_tasks(self, pass_index: int) -> list["TileTask"]:
        """What starts pass `pass_index`: its scene-wide task for an integrator with scene
        passes (which queues the tile passes once its product is stored), else the tiles."""
        if integrators.scene_passes(self.settings.integrator):
            return [self.model_copy(update={"pass_index": pass_index, "decide": False,
                                            "scene_pass": True})]
        return self.pass_tasks(pass_index)


def job_tasks(spec: JobSpec) -> list[TileTask]:
    """What a job starts with: the first pass of every tile, or, for an integrator with
    scene passes, the scene-wide task of the first iteration (which queues those tiles)."""
    s = spec.settings
    first = TileTask(job_id=spec.job_id, scene_hash=spec.scene_hash, scene_name=spec.scene_name,
                     settings=s, tile=job_tiles(s)[0],
                     priority=spec.priority, max_attempts=spec.max_attempts)
    return first.iteration_tasks(0)
