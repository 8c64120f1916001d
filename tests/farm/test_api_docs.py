"""The API's docs page, /docs (routers/apidocs.py), on a machine without internet: the
page names only files this server serves, they are Swagger UI's own (from the pinned
swagger-ui-bundle-v2 wheel), and in a real browser that can reach nothing but this
machine the page draws every operation of the schema. FastAPI's default page, which loads
Swagger UI from a CDN, is the negative control of each check."""
from __future__ import annotations

import re

import httpx
import pytest
from fastapi.openapi.docs import get_swagger_ui_html

from conftest import chromium_driver, start_api
from tessera_service.auth import PUBLIC_PATHS
from tessera_service.routers.apidocs import ASSETS, PAGE_PATHS

TOKEN = "docs-test-token-41d7"
WAIT = 120  # seconds a page condition may take on a loaded 2-core machine


@pytest.fixture(scope="module")
def base(redis_server, tmp_path_factory):
    proc, url = start_api(redis_server, tmp_path_factory.mktemp("api"), api_tokens=f"bob:{TOKEN}")
    yield url
    proc.stop()


def referenced(html: str) -> list[str]:
    """Every URL the page loads (script src, link href, img src)."""
    return re.findall(r'<(?:script|link|img)[^>]*?(?:src|href)="([^"]+)"', html)


def only_local(html: str) -> bool:
    urls = referenced(html)
    return bool(urls) and all(u.startswith("/") and not u.startswith("//") for u in urls)


def test_the_docs_page_loads_only_files_this_server_serves(base):
    from swagger_ui_bundle import swagger_ui_path

    assert PAGE_PATHS <= PUBLIC_PATHS
    anonymous = httpx.Client(base_url=base, timeout=30)  # the page is public, like /openapi.json
    page = anonymous.get("/docs")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert only_local(page.text), referenced(page.text)
    assert sorted(referenced(page.text)) == sorted(f"/docs/{name}" for name in ASSETS)
    assert "/openapi.json" in page.text
    for url in referenced(page.text):
        r = anonymous.get(url)
        name = url.rsplit("/", 1)[1]
        assert r.status_code == 200 and r.headers["content-type"] == ASSETS[name], url
        assert r.content == (swagger_ui_path / name).read_bytes(), url  # Swagger UI's own file
    # The control: FastAPI's default page fails the same check (it names a CDN).
    default = get_swagger_ui_html(openapi_url="/openapi.json", title="t").body.decode()
    assert not only_local(default) and any("cdn" in u for u in referenced(default))
    # Nothing else of the bundle is served, and ReDoc (no packaged bundle) is gone.
    assert anonymous.get("/docs/index.html").status_code == 401
    assert anonymous.get("/redoc").status_code == 401
    authed = httpx.Client(base_url=base, timeout=30, headers={"Authorization": f"Bearer {TOKEN}"})
    assert authed.get("/docs/index.html").status_code == 404
    assert authed.get("/redoc").status_code == 404


@pytest.fixture(scope="module")
def offline_browser():
    """Debian's chromium, headless, resolving no host name but this machine's address: a
    page that needs anything from the internet cannot get it."""
    driver = chromium_driver("--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1")
    yield driver
    driver.quit()


def test_the_docs_page_draws_every_operation_offline(base, offline_browser, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    schema = httpx.get(f"{base}/openapi.json", timeout=30).json()
    operations = sum(1 for item in schema["paths"].values() for method in item
                     if method in ("get", "post", "put", "delete", "patch"))
    assert operations >= 20
    driver = offline_browser
    driver.get(f"{base}/docs")
    WebDriverWait(driver, WAIT, poll_frequency=0.1).until(
        lambda d: len(d.find_elements(By.CSS_SELECTOR, ".opblock")) >= operations)
    assert len(driver.find_elements(By.CSS_SELECTOR, ".opblock")) == operations
    assert driver.find_element(By.CSS_SELECTOR, ".info .title").text.startswith("Tessera")
    driver.save_screenshot(str(tmp_path / "docs.png"))
    # The control: FastAPI's default page, in the same browser, never gets Swagger UI.
    default = tmp_path / "default.html"
    default.write_bytes(get_swagger_ui_html(openapi_url=f"{base}/openapi.json", title="t").body)
    driver.get(default.as_uri())
    WebDriverWait(driver, WAIT, poll_frequency=0.1).until(
        lambda d: d.execute_script("return document.readyState") == "complete")
    assert driver.execute_script("return typeof SwaggerUIBundle") == "undefined"
    assert not driver.find_elements(By.CSS_SELECTOR, ".opblock")
