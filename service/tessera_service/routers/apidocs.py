"""The API's docs page at /docs, served whole from this server: FastAPI's default page
loads Swagger UI from a CDN, so on a machine without internet it was blank. Its assets
come from the pinned swagger-ui-bundle-v2 package (Swagger UI 5, which reads the OpenAPI
3.1 schema FastAPI writes)."""
from __future__ import annotations

from fastapi import APIRouter, HTTPException
from fastapi.openapi.docs import get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import HTMLResponse, Response

router = APIRouter(include_in_schema=False)

DOCS = "/docs"
OAUTH2_REDIRECT = f"{DOCS}/oauth2-redirect"
# name -> media type: the only Swagger UI files served (AuthGate lets exactly these through).
ASSETS = {"swagger-ui-bundle.js": "text/javascript; charset=utf-8",
          "swagger-ui.css": "text/css; charset=utf-8",
          "favicon-32x32.png": "image/png"}
PAGE_PATHS = frozenset({DOCS, OAUTH2_REDIRECT, *(f"{DOCS}/{name}" for name in ASSETS)})


def _asset(name: str) -> bytes:
    from swagger_ui_bundle import swagger_ui_path

    return (swagger_ui_path / name).read_bytes()


@router.get(DOCS, response_class=HTMLResponse)
def docs_page() -> HTMLResponse:
    from tessera_base import __version__

    return get_swagger_ui_html(openapi_url="/openapi.json", title=f"Tessera {__version__} - API",
                               swagger_js_url=f"{DOCS}/swagger-ui-bundle.js",
                               swagger_css_url=f"{DOCS}/swagger-ui.css",
                               swagger_favicon_url=f"{DOCS}/favicon-32x32.png",
                               oauth2_redirect_url=OAUTH2_REDIRECT)


@router.get(OAUTH2_REDIRECT, response_class=HTMLResponse)
def oauth2_redirect() -> HTMLResponse:
    return get_swagger_ui_oauth2_redirect_html()


@router.get(DOCS + "/{name}")
def docs_asset(name: str) -> Response:
    if name not in ASSETS:
        raise HTTPException(404, f"no docs file {name!r}")
    # The bundle is pinned, so its files do not change while a server runs.
    return Response(_asset(name), media_type=ASSETS[name], headers={"Cache-Control": "max-age=86400"})
