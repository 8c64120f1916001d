"""The monitor page at `/` (docs/farm.md, "The monitor page"): static HTML, CSS and
JavaScript shipped with the package (tessera_service/monitor/), no build step.

The page is public and holds no data: it asks the browser for a token (kept in
sessionStorage) and reads everything through the API with `Authorization: Bearer`, like
any client. The events stream is read with fetch() rather than EventSource, which cannot
send that header; so no token ever travels in a URL (where proxies and logs keep it)."""
from __future__ import annotations

from functools import lru_cache
from html import escape
from importlib import resources

from fastapi import APIRouter, HTTPException
from fastapi.responses import HTMLResponse, Response

from tessera_base import integrators

router = APIRouter(include_in_schema=False)

# name -> media type: the only files served (AuthGate lets exactly these paths through).
ASSETS = {"monitor.js": "text/javascript; charset=utf-8", "monitor.css": "text/css; charset=utf-8"}
PAGE_PATHS = frozenset({"/", *(f"/monitor/{name}" for name in ASSETS)})
# The page's scripts come only from this server; nothing inline runs.
_HEADERS = {"Content-Security-Policy": "default-src 'self'; img-src 'self' blob:; "
                                       "object-src 'none'; base-uri 'none'; frame-ancestors 'none'",
            "X-Content-Type-Options": "nosniff", "Cache-Control": "no-cache"}


def _asset(name: str) -> str:
    return resources.files("tessera_service").joinpath("monitor", name).read_text()


@lru_cache(maxsize=1)
def _page() -> str:
    # The upload form's integrator choices are the renderer registry's (public facts, no data).
    options = "".join(f'<option value="{escape(n)}">{escape(n)}</option>'
                      for n in (*integrators.names(), "auto"))
    return _asset("index.html").replace("<!--INTEGRATORS-->", options)


@router.get("/", response_class=HTMLResponse)
def page() -> HTMLResponse:
    return HTMLResponse(_page(), headers=_HEADERS)


@router.get("/monitor/{name}")
def asset(name: str) -> Response:
    if name not in ASSETS:
        raise HTTPException(404, f"no monitor file {name!r}")
    return Response(_asset(name), media_type=ASSETS[name], headers=_HEADERS)
