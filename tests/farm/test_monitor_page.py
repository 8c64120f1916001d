"""The monitor page's serving and its place in the authentication (routers/monitor.py):
a real API with a token, no browser (tests/test_monitor_browser.py drives one)."""
from __future__ import annotations

import re
import typing

import httpx
import pytest

from conftest import start_api
from tessera_base import integrators
from tessera_base.protocol import JobState
from tessera_service.auth import PUBLIC_PATHS
from tessera_service.routers.monitor import PAGE_PATHS

TOKEN = "page-test-token-5e2a"


@pytest.fixture(scope="module")
def base(redis_server, tmp_path_factory):
    proc, url = start_api(redis_server, tmp_path_factory.mktemp("api"), api_tokens=f"bob:{TOKEN}")
    yield url
    proc.stop()


def test_the_page_and_its_files_are_public_and_nothing_else_is(base):
    assert PAGE_PATHS <= PUBLIC_PATHS
    anonymous = httpx.Client(base_url=base, timeout=30)
    page = anonymous.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "script-src" not in page.headers["content-security-policy"]  # default-src 'self'
    assert "default-src 'self'" in page.headers["content-security-policy"]
    for name, media in (("monitor.js", "text/javascript"), ("monitor.css", "text/css")):
        r = anonymous.get(f"/monitor/{name}")
        assert r.status_code == 200 and r.headers["content-type"].startswith(media)
    # Everything else needs the token: a guessed file name, the data the page shows.
    for path in ("/monitor/index.html", "/monitor/..%2Fapp.py", "/jobs", "/workers",
                 "/metrics", "/index.html"):
        assert anonymous.get(path).status_code == 401, path
    authed = httpx.Client(base_url=base, timeout=30, headers={"Authorization": f"Bearer {TOKEN}"})
    assert authed.get("/monitor/index.html").status_code == 404
    assert authed.get("/jobs").status_code == 200


def test_the_page_offers_the_registry_integrators_and_no_inline_script(base):
    text = httpx.get(f"{base}/", timeout=30).text
    offered = re.findall(r'<option value="([^"]+)">', _select(text, "integrator"))
    assert offered == [*integrators.names(), "auto"]
    # The job list's state filter offers exactly the API's job states (and "any").
    states = re.findall(r'<option value="([^"]*)">', _select(text, "filter-state"))
    assert states == ["", *typing.get_args(JobState)]
    # The content security policy allows scripts from the server only: one file, no inline code.
    assert re.findall(r"<script[^>]*>", text) == ['<script src="/monitor/monitor.js" defer>']
    assert not re.search(r"\son[a-z]+\s*=", text)  # no inline event handlers either


def _select(text: str, element_id: str) -> str:
    start = text.index(f'id="{element_id}"')
    return text[start:text.index("</select>", start)]


def test_the_page_posts_every_form_field_the_api_takes(base):
    """The upload form's field names are create_job's form fields (a renamed field there
    would otherwise silently fall back to its default)."""
    text = httpx.get(f"{base}/", timeout=30).text
    form = text[text.index('<form id="upload">'):text.index("</form>", text.index('<form id="upload">'))]
    names = set(re.findall(r'name="([a-z_]+)"', form))
    schema = httpx.get(f"{base}/openapi.json", timeout=30).json()
    body = schema["paths"]["/jobs"]["post"]["requestBody"]["content"]["multipart/form-data"]["schema"]
    ref = body["$ref"].rsplit("/", 1)[-1]
    accepted = set(schema["components"]["schemas"][ref]["properties"])
    assert names == {"file", "integrator", "width", "height", "spp", "target_error", "max_spp",
                     "priority", "denoise"}
    assert names <= accepted, names - accepted
