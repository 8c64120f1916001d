"""A job's tasks as a table (GET /jobs/{id}/tasks): one row per tile and per scene pass,
folded from what Redis already holds for the job (store.task_sources): its events (each
stored pass names its worker and seconds, each failure its worker and attempt; a stream
id is the millisecond it happened), its failure counts, and its queue (open tasks; those a
worker holds are pending in the consumer group, with the time since they were handed out).
Nothing is written for the table: it costs a read when asked for, not a write per tile."""
from __future__ import annotations

import statistics
import time
from datetime import datetime, timezone

from pydantic import ValidationError

from tessera_base import protocol
from tessera_queue import redis_schema as rdb
from tessera_queue.tasks import TileTask

from .schemas import JobTasks, TaskStatus
from .store import Job

# A tile is slow when its seconds per pass exceed this many times the job's median (a
# tile of sky beside one of glass differs by less; a stuck or thrashing tile by far more).
SLOW_FACTOR = 3.0
# ... and exceed it by this many seconds: at milliseconds per pass, noise alone triples a
# tile's time (a 15 ms tile beside 3 ms ones is nothing to look at).
SLOW_MIN_EXCESS = 1.0
# The median is only a yardstick once this many passes were timed.
MIN_TIMED_PASSES = 3


def _ms(stream_id: bytes | str) -> float:
    text = stream_id.decode() if isinstance(stream_id, bytes) else stream_id
    return int(text.split("-", 1)[0]) / 1000.0


def _when(seconds: float) -> datetime:
    return datetime.fromtimestamp(seconds, timezone.utc)


def job_tasks(job_id: str, job: Job, sources: dict, now: float | None = None) -> JobTasks:
    now = time.time() if now is None else now
    s = job.spec.settings
    grid = protocol.tile_grid(s.width, s.height, s.tile_size)
    tiles = {rect.index: TaskStatus(kind="tile", index=rect.index, x0=rect.x0, y0=rect.y0,
                                    width=rect.width, height=rect.height, state="waiting")
             for rect in grid}
    scene: dict[int, TaskStatus] = {}
    finished: set[int] = set()       # tiles whose last pass is stored
    pass_seconds: list[float] = []

    def scene_row(index: int) -> TaskStatus:
        return scene.setdefault(index, TaskStatus(kind="scene_pass", index=index, state="waiting"))

    def row_of(field: str) -> TaskStatus | None:
        kind, _, rest = field.partition(":")
        try:
            if kind == "scene":
                return scene_row(int(rest))
            return tiles.get(int(kind))
        except ValueError:
            return None

    events = sources["events"]
    complete = bool(events) and _first_is_queued(events[0][1])
    for stream_id, raw in events:
        try:
            event = rdb.JobEvent.from_fields(raw)
        except ValidationError:
            continue
        at = _ms(stream_id)
        if event.type in ("tile", "pass") and event.tile is not None and event.tile in tiles:
            row = tiles[event.tile]
            row.passes_done += 1
            row.pass_index = event.pass_index
            row.samples = event.samples
            row.finished_at = _when(at)
            if event.worker is not None:
                row.worker = event.worker
            if event.seconds is not None:
                row.render_seconds = round(row.render_seconds + event.seconds, 3)
                pass_seconds.append(event.seconds)
            if event.type == "tile":
                finished.add(event.tile)
        elif event.type == "scene_pass" and event.pass_index is not None:
            row = scene_row(event.pass_index)
            row.passes_done, row.pass_index, row.finished_at = 1, event.pass_index, _when(at)
            row.worker = event.worker or row.worker
            if event.seconds is not None:
                row.render_seconds = event.seconds
        elif event.type == "failure":
            row = row_of(event.task) if event.task else tiles.get(event.tile)
            if row is not None:
                row.last_error = event.message
                row.worker = event.worker or row.worker

    for key, count in sources["failures"].items():
        if key.startswith("tile:") and (row := row_of(key[len("tile:"):])) is not None:
            row.attempts += count
            if count >= job.spec.max_attempts:
                row.state = "failed"

    for row in tiles.values():
        if row.state == "failed":
            continue
        if row.index in finished or job.state == "done":
            row.state = "done"
        elif job.final:
            row.state = "abandoned"
    for row in scene.values():
        if row.state != "failed":
            row.state = "done" if row.passes_done else ("abandoned" if job.final else "waiting")

    for entry_id, fields in sources["open"]:
        try:
            task = TileTask.from_fields(fields)
        except (ValueError, ValidationError):
            continue
        if task.decide:
            continue  # a lockstep pass barrier: no tile of its own
        row = scene_row(task.pass_index) if task.scene_pass else tiles.get(task.tile.index)
        if row is None or row.state == "failed":
            continue
        row.pass_index = task.pass_index
        held = sources["pending"].get(entry_id)
        if held is None:
            row.state = "queued"
        else:
            consumer, idle_ms, _ = held
            row.state, row.worker = "rendering", consumer
            row.rendering_seconds = round(idle_ms / 1000.0, 3)

    median = statistics.median(pass_seconds) if len(pass_seconds) >= MIN_TIMED_PASSES else None
    if median is not None and median > 0:
        for row in tiles.values():
            per_pass = row.render_seconds / row.passes_done if row.passes_done else 0.0
            running = row.rendering_seconds if row.state == "rendering" else 0.0
            seconds = max(per_pass, running or 0.0)
            row.slow = seconds > SLOW_FACTOR * median and seconds > median + SLOW_MIN_EXCESS
    return JobTasks(id=job_id, state=job.state, tiles=[tiles[i] for i in sorted(tiles)],
                    scene_passes=[scene[i] for i in sorted(scene)],
                    median_pass_seconds=None if median is None else round(median, 3),
                    slow_factor=SLOW_FACTOR, slow_min_excess=SLOW_MIN_EXCESS,
                    events_complete=complete)


def _first_is_queued(fields: dict) -> bool:
    """The stream still starts with the job's first event (its queued state): nothing was
    trimmed."""
    try:
        event = rdb.JobEvent.from_fields(fields)
    except ValidationError:
        return False
    return event.type == "state" and event.state == "queued"
