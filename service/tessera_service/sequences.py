"""Frame ranges: a job of many frames is one ordinary job per frame (each its own tiles,
priority and fair share in the queue, its own blob keyed by the time code) plus a record
that lists them (redis_schema.sequence_key). This module turns that record into the
sequence's status: the frames' states together, and each frame's."""
from __future__ import annotations

from datetime import datetime, timezone

from .schemas import FrameStatus, SequenceStatus


def combined_state(states: list[str]) -> str:
    """The sequence's state from its frames': running while any frame runs, queued while
    any waits (and none runs), paused while one is paused and none runs; once every frame
    is final: done if all are done, else failed if one failed, else cancelled. Expired
    frames count as done (they were kept until their retention ran out)."""
    live = [s for s in states if s not in ("done", "failed", "cancelled", "expired")]
    for state in ("running", "queued", "paused"):
        if state in live:
            return state
    if all(s in ("done", "expired") for s in states):
        return "done"
    return "failed" if "failed" in states else "cancelled"


def sequence_status(sequence_id: str, record: dict) -> SequenceStatus:
    frames = []
    for frame, job_id, job in record["frames"]:
        if job is None:
            frames.append(FrameStatus(frame=frame, job=job_id, state="expired"))
        else:
            frames.append(FrameStatus(frame=frame, job=job_id, state=job.state, tiles_done=job.tiles_done,
                                      tiles_total=job.tiles_total, error=job.error))
    return SequenceStatus(
        id=sequence_id, state=combined_state([f.state for f in frames]), scene_name=record["scene_name"],
        frames=frames, tiles_done=sum(f.tiles_done for f in frames), tiles_total=sum(f.tiles_total for f in frames),
        created_at=datetime.fromtimestamp(record["created_at"], timezone.utc), warnings=record["warnings"],
        owner=record["owner"])
