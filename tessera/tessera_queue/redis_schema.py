"""Everything Tessera keeps in Redis: every key, every hash field, every event, and the
Lua scripts that move a job through its states (tessera/tessera_queue/lua/*.lua).

The service and the workers both go through this module, so they cannot disagree about
where something lives or how a job changes state. Scripts get their keys as KEYS, in the
order of `job_script_keys`; the one exception is pick.lua, which chooses the job it reads.
Single-instance Redis (no cluster).

Job hash fields (`job_key`), all written by the service at creation unless noted:
    spec             JobSpec JSON (protocol.JobSpec)
    scene_hash       the scene the job renders (its scene_jobs entry; see `scene_key`)
    state            protocol.JobState (workers: running, done, failed; service: the rest)
    priority         0-9 (protocol.DEFAULT_PRIORITY when absent); set_priority.lua changes
                     it later (the spec keeps the priority the job was submitted with)
    created_at       unix seconds; started_at (first pick) and finished_at (final state)
    tiles_total      tiles of the grid; tiles_done: tiles whose last pass is stored
    passes_done      tile passes stored
    render_seconds   sum of the tile passes' render times
    retention        seconds the job is kept after it ends (0: forever)
    warnings         JSON list of pre-flight warnings
    error            why the job failed (set when failed)
    resume_state     the state a paused job returns to
    owner            the API user who submitted it (absent on jobs from before owners;
                     see `user_jobs_key`)
    sequence         the frame range (`sequence_key`) the job is a frame of, if any
    lockstep_tiles   tile passes stored by a lockstep job, in all passes: every multiple of
                     tiles_total completes a pass and queues its barrier (store_tile.lua)
    decided_pass     the last pass whose lockstep barrier was applied (decide_pass.lua);
                     a barrier delivered twice is applied once
    product:<pass>   for an integrator with scene passes: the SHA-256 (hex) of that
                     iteration's scene-pass product, in `job_products_key` (store_product.lua;
                     set once, which queues the iteration's tile passes)
    scene_passes_stored  scene-pass products stored (one per iteration, however often a
                     scene task is delivered)
    scene_pass_runs  scene passes computed by workers, redeliveries included (workers)
"""
from __future__ import annotations

import hashlib
import re
from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from typing import Literal

import redis
from pydantic import BaseModel, ConfigDict

from tessera_base import integrators
from tessera_base.protocol import (AOV_CHANNELS, DEFAULT_PRIORITY, MAX_PRIORITY, JobState, RenderSettings,
                                   pass_range)
from tessera_base.convergence import VARIANCE_BATCHES

PREFIX = "tessera"
WORKER_GROUP = "workers"                  # the consumer group on every job's queue
JOB_INDEX = f"{PREFIX}:jobs"              # sorted set: job id -> creation time
READY = f"{PREFIX}:ready"                 # sorted set: job id -> scheduling score (see below)
ACTIVE = f"{PREFIX}:active"               # set: ids of jobs not yet in a final state
WORKERS = f"{PREFIX}:workers"             # set: names of workers that have registered
STATS = f"{PREFIX}:stats"                 # hash: farm-wide counters (for /metrics):
#                                           passes, tiles, render_seconds, failures,
#                                           poisoned, reclaimed
WAKE = f"{PREFIX}:wake"                   # list: tokens that wake idle workers (BLPOP)
WAKE_MAX = 64
DEAD_LETTER = f"{PREFIX}:dead"            # stream: poisoned tiles with their last error
DEAD_LETTER_MAXLEN = 1000
EVENTS_MAXLEN = 10000                     # per job; tile/pass/state events for SSE
LOG_MAXLEN = 1000                         # per job; lines of the job log

# Scheduling: READY's score is BAND * (MAX_PRIORITY - priority) + tiles served. The lowest
# score is served next: higher priority first, and among equal priorities the job that has
# been served least (fair share). A job (re)entering the ready set starts at the lowest
# served count of its band, so it neither starves others nor waits behind them.
BAND = 2 ** 40

_JOB = f"{PREFIX}:job:"
_QUEUE, _TILES, _EVENTS, _LOG = ":queue", ":tiles", ":events", ":log"
_FAILURES, _BLOCKLIST, _PASSES, _SPLATS = ":failures", ":blocklist", ":passes", ":splats"
_PRODUCTS = ":products"


def scene_key(scene_hash: str) -> str:
    """Hash: a scene stored once per content hash (its SHA-256). Fields: name, size (of
    the uploaded bytes, which live in the data store under scene_hash: data_store),
    retention (seconds it is kept after its last use), translated:<blob version> (the
    SHA-256 of the renderer's translated scene in the data store, recorded once by the
    first worker that translates it). The hash holds those objects (`data_holders_key`),
    so they live and die with it. No TTL while a job holds it (`scene_jobs_key`); the last
    job to end starts its retention."""
    return f"{PREFIX}:scene:{scene_hash}"


def scene_jobs_key(scene_hash: str) -> str:
    """Set: ids of the jobs not yet final that render this scene."""
    return f"{PREFIX}:scene:{scene_hash}:jobs"


def translated_field(blob_version: str) -> str:
    """The scene hash field naming (by SHA-256) the renderer's translated scene blob in the
    data store, per blob version
    so that an upgraded worker never reads an old blob as new."""
    return f"translated:{blob_version}"


def preflight_key(scene_hash: str, suffix: str, variants: Sequence[str] = ()) -> str:
    """String: the pre-flight inspection result (JSON) of a scene, so that a scene that was
    already validated is not inspected again; for a refused scene {"error", ...}, so that
    it is refused again at once. Both hold the limits they were reached under, and count
    only under the same. The same bytes mean another scene under another `suffix` (a
    .usdz's root is its first member, a .zip's the one its comment names; text bytes are
    no .usdc): each suffix its own key, so that an upload under a wrong suffix neither
    passes nor refuses the genuine one. With `variants` (a job's selections, in order)
    the stage composes differently: its own key, by their digest. TTL: the scene
    retention. Only the API reads it."""
    base = f"{PREFIX}:preflight:{scene_hash}:{suffix.lower().lstrip('.')}"
    if not variants:
        return base
    digest = hashlib.sha256("\n".join(variants).encode()).hexdigest()[:16]
    return f"{base}:variants:{digest}"


def blob_key(content_hash: str) -> str:
    """String: the size of one file of a packed scene (content-addressed upload: PUT
    /blobs/<sha256>), whose bytes, verified when stored, live in the data store under
    their SHA-256 (hex); this key holds them there (`data_holders_key`). A manifest of
    such files (relative path -> hash) is assembled into a zip bundle that is then stored
    as a scene (`scene_key`). TTL: the scene retention, renewed whenever a client asks
    for it or a manifest uses it. Only the API reads or writes it."""
    return f"{PREFIX}:blob:{content_hash}"


DATA_STORE_ID = f"{PREFIX}:data:store-id"   # string: this farm's folder in the data directory
DATA_OBJECTS = f"{PREFIX}:data:objects"     # set: SHA-256 of every object in the data store


def data_key(content_hash: str) -> str:
    """Hash: one object of the data store (tessera_queue.data_store), whose bytes are the
    file named by its SHA-256 in the shared data directory. Fields: size. No TTL: it goes
    with its file when the store's sweep finds no holder left."""
    return f"{PREFIX}:data:{content_hash}"


def data_holders_key(content_hash: str) -> str:
    """Set: the Redis keys (`blob_key`, `scene_key`) that need the object; it is kept
    while one of them exists."""
    return f"{PREFIX}:data:{content_hash}:holders"


def blob_owners_key(content_hash: str) -> str:
    """Set: the API users who sent the bytes of `blob_key(content_hash)` themselves. Only
    they may use the file in a manifest or hear that the farm has it: a hash is no proof
    of possession (a user who learnt another's texture's SHA-256 rendered its content).
    TTL: the blob's. Only the API reads or writes it."""
    return f"{PREFIX}:blob-owners:{content_hash}"


def blob_usage_key(user: str) -> str:
    """Hash: the blobs an API user sent (sha256 -> size in bytes), for the user's quota
    (Settings.user_blob_quota_bytes) and DELETE /blobs. Entries whose blob expired are
    pruned when the quota is checked. TTL: the scene retention, renewed with the user's
    uploads. Only the API reads or writes it."""
    return f"{PREFIX}:blob-usage:{user}"


def job_key(job_id: str) -> str:
    """Hash: the job's spec, state, counters and timings (fields: module docstring)."""
    return f"{_JOB}{job_id}"


def job_queue_key(job_id: str) -> str:
    """Stream of the job's open TileTask messages, read through the WORKER_GROUP group.
    Entries are deleted once acknowledged, so the stream holds only open work."""
    return f"{_JOB}{job_id}{_QUEUE}"


def job_tiles_key(job_id: str) -> str:
    """Hash: result_field(tile, pass) -> encoded TileResult. Written with HSETNX, so a
    pass rendered twice (at-least-once delivery) is stored once. Results of splatting
    integrators carry an empty splat layer: their splats are summed in `job_splats_key`."""
    return f"{_JOB}{job_id}{_TILES}"


def job_splats_key(job_id: str) -> str:
    """Hash: the job's light-tracing splats summed over tiles (tessera_base.film.SplatSums):
    "<pass>" -> that pass's splats, "<pass>:<batch>" -> a variance batch's. A field is
    rewritten with every tile pass (store_tile.lua, under WATCH), so storage is one
    full-frame layer per pass and batch, whatever the number of tiles."""
    return f"{_JOB}{job_id}{_SPLATS}"


def job_products_key(job_id: str) -> str:
    """Hash: SHA-256 hex -> a scene-pass product (opaque bytes, tessera_base.film.run_scene_pass),
    content-addressed and written once (HSETNX); the job hash's product:<pass> fields say
    which iteration uses which. Workers fetch a product once and keep it by its hash. A
    pass's product is deleted when its barrier is decided (decide_pass.lua): at most the
    current iteration's is held."""
    return f"{_JOB}{job_id}{_PRODUCTS}"


def product_field(pass_index: int) -> str:
    """The job hash's field naming iteration pass_index's product."""
    return f"product:{pass_index}"


def scene_task_field(pass_index: int) -> str:
    """A scene task's name where a tile pass has its result field (failure counts)."""
    return f"scene:{pass_index}"


def job_events_key(job_id: str) -> str:
    """Stream of progress events (fields: `JobEvent`)."""
    return f"{_JOB}{job_id}{_EVENTS}"


def job_log_key(job_id: str) -> str:
    """List of log lines (oldest first), capped at LOG_MAXLEN."""
    return f"{_JOB}{job_id}{_LOG}"


def job_failures_key(job_id: str) -> str:
    """Hash: "tile:<result field>" -> failed attempts, "worker:<name>" -> failures there."""
    return f"{_JOB}{job_id}{_FAILURES}"


def job_passes_key(job_id: str) -> str:
    """String: a lockstep job's PassAccumulator after its last decided pass."""
    return f"{_JOB}{job_id}{_PASSES}"


def job_blocklist_key(job_id: str) -> str:
    """Set: workers that no longer take this job's tiles."""
    return f"{_JOB}{job_id}{_BLOCKLIST}"


def job_image_key(job_id: str, fmt: Literal["exr", "png"]) -> str:
    """String: the merged image of a done job (EXR or PNG preview bytes), cached by the
    service so that repeated downloads do not re-merge the tiles."""
    return f"{_JOB}{job_id}:image.{fmt}"


_SEQUENCE = f"{PREFIX}:sequence:"


def sequence_key(sequence_id: str) -> str:
    """Hash: a frame range submitted as one job (POST /jobs with `frames`); each frame is
    an ordinary job. Fields: frames (JSON [[frame, job id], ...] in the order submitted),
    scene_name, owner (absent: nobody's), created_at, warnings (JSON). Written once by the
    service; it expires SEQUENCE_TTL_FACTOR x the job retention after its last read."""
    return f"{_SEQUENCE}{sequence_id}"


SEQUENCE_TTL_FACTOR = 2


def job_keys(job_id: str) -> list[str]:
    """Every key of one job (for expiry and deletion)."""
    return [job_key(job_id), job_queue_key(job_id), job_tiles_key(job_id), job_splats_key(job_id),
            job_events_key(job_id), job_log_key(job_id), job_failures_key(job_id),
            job_blocklist_key(job_id), job_passes_key(job_id), job_products_key(job_id),
            job_image_key(job_id, "exr"), job_image_key(job_id, "png")]


def job_script_keys(job_id: str, scene_hash: str) -> list[str]:
    """KEYS of every script that moves a job, in the order job.lua names them."""
    return [job_key(job_id), job_queue_key(job_id), job_tiles_key(job_id), job_events_key(job_id),
            job_log_key(job_id), job_failures_key(job_id), job_blocklist_key(job_id),
            job_passes_key(job_id), job_splats_key(job_id), READY, ACTIVE, WAKE, STATS,
            scene_key(scene_hash), scene_jobs_key(scene_hash), job_products_key(job_id)]


def user_jobs_key(user: str) -> str:
    """Sorted set: ids of the jobs `user` submitted -> creation time (the job hash's
    `owner` field says the same; entries of expired jobs are dropped when listed)."""
    return f"{PREFIX}:user:{user}:jobs"


def worker_key(worker_name: str) -> str:
    """Hash with a TTL, present while the worker is alive (its heartbeat): host, pid,
    started_at, beat_at, current ("job/tile/pass" or ""), tiles_done, failures, reaps
    (times its reaper looked for dead workers' tiles), disabled ("1": an admin disabled it
    (POST /workers/{name}/disable): it takes no new task; set only while the hash lives)."""
    return f"{PREFIX}:worker:{worker_name}"


def result_field(tile_index: int, pass_index: int) -> str:
    """The job_tiles_key field of one tile pass."""
    return f"{tile_index}:{pass_index}"


# ------------------------------------------------------------------ storage bound
_RESULT_HEADER = 128   # a tile result's header and section lengths, rounded up
_TASK_BYTES = 1024     # one queued TileTask (JSON) in the queue stream
_EVENT_BYTES = 224     # one event stream entry (with its worker name and seconds)


def job_storage_bound(settings: RenderSettings) -> int:
    """An upper bound on the bytes one job keeps in Redis (docs/farm.md, "Memory per
    job"), from its settings alone: the service refuses a job above its budget before
    queuing it. With P passes (the pass schedule's length), N = width * height pixels, T
    tiles and B variance batches (convergence.VARIANCE_BATCHES with the variance AOV of a
    splatting integrator, else 0):
        tile results   P * (N * (16 + 12 [variance] + 4 * AOV channels + 12 * B) + T * 128)
        splat sums     P * (1 + B) * N * 24        (splatting integrators; int64 RGB, raw)
        lockstep sums  N * 16                      (PassAccumulator)
        images         N * (16 + 4 * AOV channels + 4 [+ 12 denoised])  (cached EXR, PNG)
        queue, events  T * (1024 + P * 224)
    Splat sums are one full-frame layer per pass however many tiles there are (their
    stored size is zlib'd and usually far smaller)."""
    s = settings
    pixels = s.width * s.height
    tiles = -(-s.width // s.tile_size) * -(-s.height // s.tile_size)
    passes = 0
    while pass_range(s, passes) is not None:
        passes += 1
    channels = sum(AOV_CHANNELS[a] for a in s.aovs if a in AOV_CHANNELS)
    splats = integrators.splats(s.integrator)
    batches = VARIANCE_BATCHES if splats and "variance" in s.aovs else 0
    variance = 12 if (s.adaptive or "variance" in s.aovs) else 0
    results = passes * (pixels * (16 + variance + 4 * channels + 12 * batches)
                        + tiles * _RESULT_HEADER)
    sums = passes * (1 + batches) * pixels * 24 if splats else 0
    lockstep = pixels * 16 if s.lockstep else 0
    images = pixels * (16 + 4 * channels + 4 + (12 if "variance" in s.aovs else 0)
                       + (12 if s.denoise else 0))  # the EXR's denoised.R/G/B
    return results + sums + lockstep + images + tiles * (_TASK_BYTES + passes * _EVENT_BYTES)


# ------------------------------------------------------------------ events
class JobEvent(BaseModel):
    """One entry of a job's event stream (also sent as SSE `data`). The Lua scripts write
    these fields; the service's emitter and the SSE reader go through this model."""

    model_config = ConfigDict(extra="forbid")

    type: Literal["state", "tile", "pass", "failure", "scene_pass"]
    state: JobState | None = None
    tile: int | None = None
    pass_index: int | None = None
    samples: int | None = None
    tiles_done: int | None = None
    message: str | None = None
    # tile and pass events: the worker that stored the pass and its render seconds;
    # failure events: the worker, the failed task's result field (`result_field` or
    # `scene_task_field`) and which attempt at it this was. (GET /jobs/{id}/tasks folds them.)
    worker: str | None = None
    seconds: float | None = None
    task: str | None = None
    attempt: int | None = None

    def to_fields(self) -> dict[str, str]:
        return {k: str(v) for k, v in self.model_dump(exclude_none=True).items()}

    @classmethod
    def from_fields(cls, fields: dict) -> "JobEvent":
        return cls.model_validate({(k.decode() if isinstance(k, bytes) else k):
                                   (v.decode() if isinstance(v, bytes) else v)
                                   for k, v in fields.items()})


# ------------------------------------------------------------------ scripts
_CONSTANTS = {
    "EVENTS_MAXLEN": EVENTS_MAXLEN, "LOG_MAXLEN": LOG_MAXLEN, "BAND": BAND,
    "MAX_PRIORITY": MAX_PRIORITY, "DEFAULT_PRIORITY": DEFAULT_PRIORITY, "WAKE_MAX": WAKE_MAX,
    "WORKER_GROUP": WORKER_GROUP, "DEAD_LETTER_MAXLEN": DEAD_LETTER_MAXLEN,
    "QUEUE": _QUEUE, "EVENTS": _EVENTS, "LOG": _LOG, "BLOCKLIST": _BLOCKLIST,
}
# Scripts that take job_script_keys (job.lua is prepended to them).
JOB_SCRIPTS = ("admit_job", "fail_job", "cancel_job", "pause_job", "resume_job", "store_tile",
               "decide_pass", "fail_tile", "store_product", "set_priority", "hand_back")
OTHER_SCRIPTS = ("pick", "touch_scene", "drop_idle_consumer")


def _lua(name: str) -> str:
    return resources.files("tessera_queue").joinpath("lua", f"{name}.lua").read_text()


@lru_cache(maxsize=None)
def script_source(name: str) -> str:
    """The full text of one script: common.lua (and job.lua for job scripts) + its own
    file, with the @NAME@ constants filled in."""
    if name not in JOB_SCRIPTS + OTHER_SCRIPTS:
        raise KeyError(f"no script {name!r}")
    parts = [_lua("common")] + ([_lua("job")] if name in JOB_SCRIPTS else []) + [_lua(name)]
    text = "\n".join(parts)
    for key, value in _CONSTANTS.items():
        text = text.replace(f"@{key}@", str(value))
    left = re.search(r"@[A-Z_]+@", text)
    if left:
        raise RuntimeError(f"script {name} has an unfilled constant {left.group()}")
    return text


class Scripts:
    """Every script registered once on one client (EVALSHA, loaded on first use)."""

    def __init__(self, client: redis.Redis):
        for name in JOB_SCRIPTS + OTHER_SCRIPTS:
            setattr(self, name, client.register_script(script_source(name)))

    admit_job: redis.commands.core.Script
    fail_job: redis.commands.core.Script
    cancel_job: redis.commands.core.Script
    pause_job: redis.commands.core.Script
    resume_job: redis.commands.core.Script
    store_tile: redis.commands.core.Script
    decide_pass: redis.commands.core.Script
    fail_tile: redis.commands.core.Script
    store_product: redis.commands.core.Script
    set_priority: redis.commands.core.Script
    hand_back: redis.commands.core.Script
    pick: redis.commands.core.Script
    touch_scene: redis.commands.core.Script
    drop_idle_consumer: redis.commands.core.Script


def job_prefix() -> str:
    """pick.lua's ARGV[3]: job_key(id) == job_prefix() + id."""
    return _JOB
