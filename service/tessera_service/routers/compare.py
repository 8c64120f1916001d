"""/compare: the noise-aware comparison of two uploaded EXRs (tessera_tools.compare), as JSON."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Annotated, Callable

from fastapi import APIRouter, File, Form, HTTPException, Request, Response, UploadFile
from fastapi.routing import APIRoute
from starlette.types import Message

from tessera_tools.compare import ALPHA, CompareReport

from ..compare_process import CompareRefused, compare_in_child
from ..inspection_pool import InspectionPool, PoolFull
from ..settings import Settings
from .submit import _save_upload, upload_too_large

FILES = 2
FORM_OVERHEAD = 1 << 20


class _LimitedBody(APIRoute):
    """Refuses a request body larger than two uploads (Settings.max_upload_bytes each) plus
    the form around them before FastAPI spools it to disk: at once if Content-Length says
    so, else as soon as the streamed body grows past it."""

    def get_route_handler(self) -> Callable:
        handler = super().get_route_handler()

        async def limited(request: Request) -> Response:
            limit = request.app.state.settings.max_upload_bytes
            max_body = FILES * limit + FORM_OVERHEAD
            length = request.headers.get("content-length")
            if length is not None and length.isdigit() and int(length) > max_body:
                raise upload_too_large(limit)
            received = 0
            receive = request.receive

            async def limited_receive() -> Message:
                nonlocal received
                message = await receive()
                if message["type"] == "http.request":
                    received += len(message.get("body", b""))
                    if received > max_body:
                        raise upload_too_large(limit)
                return message

            return await handler(Request(request.scope, limited_receive))

        return limited


router = APIRouter(tags=["compare"], route_class=_LimitedBody)


@router.post("/compare", response_model=CompareReport,
             responses={413: {"description": "an upload is larger than the limit, an image has "
                                             "more pixels than compare_max_pixels, or the "
                                             "comparison ran out of its memory limit"},
                        429: {"description": "too many comparisons running and waiting"},
                        422: {"description": "not comparable: unreadable EXR, sizes differ, no "
                                             "variance channels, bad alpha"}})
def compare(
    request: Request,
    test: Annotated[UploadFile, File(description="EXR to check (with variance.R/G/B and spp "
                                                 "channels, as `tessera render` writes)")],
    reference: Annotated[UploadFile, File(description="EXR to check against")],
    alpha: Annotated[float, Form(gt=0, lt=1, description="false-alarm rate when the renders "
                                                        "agree")] = ALPHA,
    method: Annotated[str, Form(pattern="^(bh|bonferroni)$",
                                description="bh (Benjamini-Hochberg) or bonferroni")] = "bh",
    flip: Annotated[bool, Form(description="also compute the LDR FLIP metric")] = True,
) -> CompareReport:
    """Do TEST and REFERENCE differ beyond their noise? Per-pixel Welch t-tests plus block
    tests with a multiple-comparison correction (docs/accuracy.md). Returns the report; its
    `verdict` is "same" or "differs" (the CLI's exit codes 0 and 1)."""
    settings: Settings = request.app.state.settings
    with tempfile.TemporaryDirectory(prefix=f"tessera-compare-{os.getpid()}-") as tmp:
        paths = []
        for role, upload in (("test", test), ("reference", reference)):
            path = Path(tmp, f"{role}.exr")
            _save_upload(upload, path, settings.max_upload_bytes)
            paths.append(path)
        pool: InspectionPool = request.app.state.comparisons
        try:
            with pool.slot():
                return CompareReport(**compare_in_child(
                    *paths, alpha=alpha, method=method, flip=flip,
                    max_pixels=settings.compare_max_pixels,
                    memory_bytes=settings.compare_memory_bytes, timeout=settings.compare_timeout))
        except PoolFull as exc:
            raise HTTPException(429, str(exc), headers={"Retry-After": "5"}) from None
        except CompareRefused as exc:
            # The temporary names mean nothing to the client: name the uploads instead.
            message = str(exc).replace(str(paths[0]), test.filename or "test") \
                              .replace(str(paths[1]), reference.filename or "reference")
            raise HTTPException(exc.status, message) from None
