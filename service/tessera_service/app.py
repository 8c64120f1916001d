"""The FastAPI application. Run with: uvicorn --factory tessera_service.app:create_app"""
from __future__ import annotations

import asyncio
import logging
import math
from contextlib import asynccontextmanager

import redis
import redis.asyncio
from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import tessera_base
from tessera_base.process import remove_orphaned_tempdirs

from .auth import AuthGate, parse_networks, require_user
from .http_guard import accept_error_handler
from .inspection_pool import InspectionPool
from .redis_acl import aof_replay_problem, redacted
from .routers import actions, apidocs, blobs, compare, farm, jobs, monitor, priority, scaling, submit, tasks, workers
from .schemas import Health, Problem
from .settings import Settings
from .store import JobStore
from .users import UserDirectory

log = logging.getLogger("tessera.service")

# Room for the multipart framing and the small form fields around the file itself.
FORM_OVERHEAD = 1 << 20


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    users = UserDirectory(settings.api_tokens, settings.api_admins)  # a bad entry stops here
    trusted_proxies = parse_networks(settings.trusted_proxies)
    if not users and not settings.allow_anonymous_loopback:
        log.error("no API tokens (TESSERA_API_TOKENS) and anonymous loopback access is off "
                  "(TESSERA_ALLOW_ANONYMOUS_LOOPBACK): every request but /healthz is refused")
    store = JobStore.from_url(settings.redis_url, retention=settings.job_retention,
                              scene_retention=settings.scene_retention, data_dir=settings.data_dir)
    aredis = redis.asyncio.Redis.from_url(settings.redis_url, socket_connect_timeout=5,
                                          socket_timeout=30, health_check_interval=30)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        # A failed accept (out of descriptors) is one log line a minute, not a traceback each.
        asyncio.get_running_loop().set_exception_handler(accept_error_handler)
        # What a killed API left: uploads (users' scenes), merges and compares in progress,
        # and the bundles its inspections unpacked.
        for kind in ("upload", "merge", "compare", "bundle"):
            for path in remove_orphaned_tempdirs(kind):
                log.warning("removed %s, left by an API process that was killed", path)
        if not store.ping():  # not fatal: /healthz reports it, requests retry
            log.warning("redis at %s is not reachable yet", redacted(settings.redis_url))
        else:
            # Refused at once, before any job is accepted that a restart of Redis would lose.
            problem = aof_replay_problem(store.redis)
            if problem is not None:
                log.critical("refusing to start: %s", problem)
                raise RuntimeError(f"tessera API: {problem}")
        problem = store.data.unusable()
        if problem is not None:
            log.critical("refusing to start: %s", problem)
            raise RuntimeError(f"tessera API: {problem}")
        sweeper = asyncio.create_task(_sweep_data(store, settings.data_sweep_seconds))
        yield
        sweeper.cancel()
        store.redis.close()
        await aredis.aclose()

    # /docs is served from the package (routers/apidocs.py), not FastAPI's CDN page; ReDoc
    # has no packaged bundle, and a page that is blank offline is left out.
    app = FastAPI(title="Tessera", version=tessera_base.__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None,
                  description="Render farm: submit a USD scene, get an EXR. Every endpoint "
                              "but /healthz needs `Authorization: Bearer <token>` when the "
                              "server is configured with tokens (TESSERA_API_TOKENS). A token "
                              "names a user, who sees and controls only their own jobs; "
                              "admins (TESSERA_API_ADMINS) see all.")
    app.state.settings = settings
    app.state.users = users
    app.state.inspections = InspectionPool(settings.preflight_concurrency, settings.preflight_queue,
                                           wait_seconds=settings.preflight_timeout)
    # Each comparison's child may use compare_memory_bytes: bound how many run at once.
    app.state.comparisons = InspectionPool(settings.compare_concurrency, settings.preflight_queue,
                                           wait_seconds=settings.compare_timeout,
                                           activity="comparing {n} other image pair(s)")
    app.state.store = store
    # Verified blobs being read back and stored in Redis at once (each up to the upload limit).
    app.state.blob_slots = asyncio.Semaphore(settings.blob_store_concurrency)
    # Uploads in flight per user (routers/blobs.py, upload_slot); one event loop, no lock.
    app.state.uploads_in_flight = {}
    app.state.aredis = aredis  # for the event streams
    errors = {401: {"model": Problem, "description": "missing or invalid bearer token"},
              503: {"model": Problem, "description": "the job store (redis) is unavailable"}}
    app.include_router(submit.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(jobs.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(farm.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(compare.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(priority.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(tasks.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(actions.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(workers.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(monitor.router)  # public static page: AuthGate lets only its paths through
    app.include_router(apidocs.router)  # public as well: the docs page and its Swagger UI files
    app.include_router(blobs.router, dependencies=[Depends(require_user)], responses=errors)
    app.include_router(scaling.router, dependencies=[Depends(require_user)], responses=errors)
    app.add_middleware(UploadLimit, path="/jobs",
                       max_bytes=settings.max_upload_bytes + FORM_OVERHEAD,
                       file_limit=settings.max_upload_bytes)
    # Added last, so it runs first: nothing reads a body before the user is known.
    app.add_middleware(AuthGate, users=users,
                       allow_anonymous_loopback=settings.allow_anonymous_loopback,
                       trusted_proxies=trusted_proxies, allowed_hosts=settings.allowed_hosts)

    @app.get("/healthz", response_model=Health, tags=["health"])
    def healthz() -> JSONResponse:
        """200 while the API and Redis answer (a load balancer keeps routing); the body
        says degraded when the farm is not rendering: no live worker, or work in the queue
        that has not moved for `stall_seconds`. 503 when Redis is unreachable."""
        if not store.ping():
            return JSONResponse(Health(status="redis unreachable", redis=False).model_dump(), status_code=503)
        workers = len(store.workers())
        problems = [] if workers else ["no worker is alive (no current heartbeat)"]
        idle = store.seconds_since_progress()
        if idle is not None and idle > settings.stall_seconds:
            problems.append(f"queued or running jobs have not progressed for {idle:.0f} s")
        return JSONResponse(Health(status="degraded" if problems else "ok", redis=True, workers=workers,
                                   problems=problems).model_dump())

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's own handler echoes each error's input, and JSON has no NaN or Infinity:
        # target_error=nan answered 500. Non-finite numbers are echoed as text.
        return JSONResponse({"detail": _json_safe(jsonable_encoder(exc.errors()))}, status_code=422)

    @app.exception_handler(redis.ConnectionError)
    @app.exception_handler(redis.TimeoutError)
    async def redis_unavailable(request: Request, exc: redis.RedisError) -> JSONResponse:
        return JSONResponse({"detail": f"the job store (redis) is unavailable: {exc}"},
                            status_code=503)

    @app.exception_handler(redis.exceptions.OutOfMemoryError)
    async def redis_full(request: Request, exc: redis.RedisError) -> JSONResponse:
        # noeviction: Redis refused a write (MULTI blocks are refused whole), so nothing of
        # this request was half-stored; accepted work goes on once there is room.
        return JSONResponse({"detail": "the job store (redis) is full (its maxmemory): nothing was "
                                       "stored; try again when running jobs have finished"},
                            status_code=503, headers={"Retry-After": "30"})

    return app


async def _sweep_data(store: JobStore, period: float) -> None:
    """Deletes the data store's objects that nothing holds (data_store.sweep), at start and
    every `period` seconds; a failure (Redis down, a disk error) waits for the next."""
    while True:
        try:
            count, freed = await asyncio.to_thread(store.data.sweep)
            if count:
                log.info("data sweep: deleted %d file(s) nothing holds, %d bytes", count, freed)
        except (redis.RedisError, OSError) as exc:
            log.warning("data sweep of %s failed: %s", store.data.root, exc)
        await asyncio.sleep(period)


def _json_safe(value):
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


class UploadLimit:
    """Refuses request bodies over max_bytes on POST `path` before they are spooled to disk:
    at once if Content-Length says so, else as soon as the streamed body grows too large.
    (The route then checks the file itself against the exact limit.)"""

    def __init__(self, app: ASGIApp, path: str, max_bytes: int, file_limit: int):
        self.app, self.path, self.max_bytes, self.file_limit = app, path, max_bytes, file_limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST" or scope["path"].rstrip("/") != self.path:
            await self.app(scope, receive, send)
            return
        too_large = submit.upload_too_large(self.file_limit)
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.max_bytes:
            await JSONResponse({"detail": too_large.detail}, status_code=413)(scope, receive, send)
            return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    # Raised inside the request's body parsing: FastAPI passes an
                    # HTTPException through and answers 413.
                    raise HTTPException(413, too_large.detail)
            return message

        await self.app(scope, limited_receive, send)
