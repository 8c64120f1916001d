"""The FastAPI application. Run with: uvicorn --factory tessera_service.app:create_app"""
from __future__ import annotations

import logging
from contextlib import asynccontextmanager

import redis
from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .routers import jobs
from .schemas import Health
from .settings import Settings
from .store import JobStore

log = logging.getLogger("tessera.service")

# Room for the multipart framing and the small form fields around the file itself.
FORM_OVERHEAD = 1 << 20


def create_app(settings: Settings | None = None) -> FastAPI:
    settings = settings or Settings()
    store = JobStore.from_url(settings.redis_url)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        try:
            store.ensure_group()
        except redis.RedisError as e:  # not fatal: /healthz reports it, requests retry
            log.warning("redis at %s is not reachable yet: %s", settings.redis_url, e)
        yield
        store.redis.close()

    app = FastAPI(title="Tessera", version="0.1.0", lifespan=lifespan,
                  description="Render farm: submit a USD scene, get an EXR.")
    app.state.settings = settings
    app.state.store = store
    app.include_router(jobs.router)
    app.add_middleware(UploadLimit, path="/jobs",
                       max_bytes=settings.max_upload_bytes + FORM_OVERHEAD,
                       file_limit=settings.max_upload_bytes)

    @app.get("/healthz", response_model=Health, tags=["health"])
    def healthz() -> JSONResponse:
        ok = store.ping()
        return JSONResponse(Health(status="ok" if ok else "redis unreachable", redis=ok).model_dump(),
                            status_code=200 if ok else 503)

    @app.exception_handler(redis.ConnectionError)
    @app.exception_handler(redis.TimeoutError)
    async def redis_unavailable(request: Request, exc: redis.RedisError) -> JSONResponse:
        return JSONResponse({"detail": f"the job store (redis) is unavailable: {exc}"},
                            status_code=503)

    return app


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
        too_large = jobs.upload_too_large(self.file_limit)
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
