"""The per-tile table's fold (tasks_view.job_tasks) on authored sources: the events, failure
counts and queue a job of four tiles would leave in Redis, with every expected value
written here (no farm: tests/farm/test_monitor_api.py checks the same on a real one)."""
from __future__ import annotations

from datetime import datetime, timezone

from tessera_base.protocol import JobSpec, RenderSettings
from tessera_queue import redis_schema as rdb
from tessera_queue.tasks import TileTask, job_tasks as first_tasks
from tessera_service.store import Job
from tessera_service.tasks_view import SLOW_FACTOR, SLOW_MIN_EXCESS, job_tasks

SETTINGS = RenderSettings(width=64, height=64, spp=4, tile_size=32)  # tiles 0-3, 32x32
SPEC = JobSpec(job_id="a" * 32, scene_hash="b" * 64, scene_name="x.usda", settings=SETTINGS,
               max_attempts=3)
T0 = 1_800_000_000_000  # ms: the events' stream ids


def event(ms: int, **fields) -> tuple[bytes, dict]:
    return (f"{ms}-0".encode(), {k.encode(): str(v).encode()
                                 for k, v in rdb.JobEvent(**fields).to_fields().items()})


def job(state: str) -> Job:
    return Job(spec=SPEC, state=state, tiles_total=4, tiles_done=2, passes_done=2,
               created_at=T0 / 1000, started_at=None, finished_at=None, render_seconds=0.0,
               warnings=[], error=None)


def sources(failures: dict[str, int], open_tiles: dict[int, tuple[str, int] | None],
            scale: float = 1.0) -> dict:
    """Tiles 0-2 stored in 0.5, 0.7 and 0.6 s (times `scale`): the median pass 0.6 s."""
    events = [event(T0, type="state", state="queued"),
              event(T0 + 1000, type="tile", tile=0, pass_index=0, samples=4, tiles_done=1,
                    worker="w-a", seconds=0.5 * scale),
              event(T0 + 2000, type="failure", tile=1, message="the renderer crashed", worker="w-b",
                    task="1:0", attempt=1),
              event(T0 + 3000, type="tile", tile=2, pass_index=0, samples=4, tiles_done=2,
                    worker="w-b", seconds=0.7 * scale),
              event(T0 + 3500, type="tile", tile=1, pass_index=0, samples=4, tiles_done=3,
                    worker="w-a", seconds=0.6 * scale)]
    grid = first_tasks(SPEC)
    entries, pending = [], {}
    for i, (tile, held) in enumerate(open_tiles.items()):
        entry = f"{T0 + 4000 + i}-0".encode()
        entries.append((entry, {b"task": grid[tile].model_dump_json().encode()}))
        if held is not None:
            pending[entry] = (held[0], held[1], 1)
    return {"events": events, "failures": failures, "open": entries, "pending": pending}


def test_tiles_fold_from_events_failures_and_queue():
    # Tile 3 held by w-c for 9.5 s: slow (the median pass is 0.6 s; 9.5 > 3 x 0.6).
    table = job_tasks(SPEC.job_id, job("running"),
                      sources({"tile:1:0": 1, "worker:w-b": 1}, {3: ("w-c", 9500)}))
    rows = {t.index: t for t in table.tiles}
    assert table.events_complete and table.median_pass_seconds == 0.6
    assert (rows[0].state, rows[0].worker, rows[0].render_seconds, rows[0].samples) == ("done", "w-a", 0.5, 4)
    assert rows[0].finished_at == datetime.fromtimestamp((T0 + 1000) / 1000, timezone.utc)
    assert (rows[0].x0, rows[0].y0, rows[0].width, rows[0].height) == (0, 0, 32, 32)
    assert (rows[1].state, rows[1].attempts, rows[1].last_error, rows[1].worker) == (
        "done", 1, "the renderer crashed", "w-a")
    assert (rows[3].state, rows[3].worker, rows[3].rendering_seconds) == ("rendering", "w-c", 9.5)
    assert [t.index for t in table.tiles if t.slow] == [3]
    # Negative control: held for just under SLOW_FACTOR x the median it is not slow (1.79 s:
    # the excess over the median, 1.19 s, is past SLOW_MIN_EXCESS, so the factor decides).
    assert SLOW_FACTOR * 0.6 - 0.01 - 0.6 > SLOW_MIN_EXCESS
    under = job_tasks(SPEC.job_id, job("running"),
                      sources({}, {3: ("w-c", int(SLOW_FACTOR * 600) - 10)}))
    assert not any(t.slow for t in under.tiles)
    # Tiles of milliseconds (median 6 ms): one held 20x the median but less than
    # SLOW_MIN_EXCESS over it is not slow; held just past that excess it is.
    fast = lambda held_ms: job_tasks(SPEC.job_id, job("running"),  # noqa: E731
                                     sources({}, {3: ("w-c", held_ms)}, scale=0.01)).tiles[3].slow
    assert not fast(int((0.006 + SLOW_MIN_EXCESS) * 1000) - 10) and fast(int((0.006 + SLOW_MIN_EXCESS) * 1000) + 10)
    # Queued (not held) is queued, on nobody.
    queued = job_tasks(SPEC.job_id, job("running"), sources({}, {3: None}))
    assert (queued.tiles[3].state, queued.tiles[3].worker) == ("queued", None)


def test_a_tile_whose_attempts_ran_out_is_failed_and_the_rest_abandoned():
    table = job_tasks(SPEC.job_id, job("failed"), sources({"tile:3:0": 3}, {}))
    assert [t.state for t in table.tiles] == ["done", "done", "done", "failed"]
    assert table.tiles[3].attempts == 3
    # One attempt short it is not failed: the job ended without it.
    short = job_tasks(SPEC.job_id, job("failed"), sources({"tile:3:0": 2}, {}))
    assert short.tiles[3].state == "abandoned"


def test_a_trimmed_stream_says_so():
    src = sources({}, {})
    src["events"] = src["events"][1:]
    assert not job_tasks(SPEC.job_id, job("running"), src).events_complete


def test_scene_passes_are_rows_of_their_own():
    spec = SPEC.model_copy(update={"settings": SETTINGS})
    scene_task = TileTask(job_id=spec.job_id, scene_hash=spec.scene_hash, scene_name="x.usda",
                          settings=SETTINGS, tile=first_tasks(SPEC)[0].tile, pass_index=1,
                          scene_pass=True)
    src = {"events": [event(T0, type="state", state="queued"),
                      event(T0 + 10, type="scene_pass", pass_index=0, worker="w-b", seconds=1.5)],
           "failures": {"tile:scene:1": 2},
           "open": [(b"9-0", {b"task": scene_task.model_dump_json().encode()})],
           "pending": {b"9-0": ("w-a", 100, 3)}}
    table = job_tasks(SPEC.job_id, job("running"), src)
    assert [(s.index, s.state, s.attempts, s.worker, s.render_seconds) for s in table.scene_passes] == [
        (0, "done", 0, "w-b", 1.5), (1, "rendering", 2, "w-a", 0.0)]
    assert table.median_pass_seconds is None  # no timed tile pass yet
