"""Fuzzing the HTTP API from its own OpenAPI schema (Schemathesis): whatever a client sends
that the schema allows, or nearly allows, the server never answers 5xx. Runs against a real
uvicorn process and redis-server, with bearer-token auth on."""
from __future__ import annotations

import json

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis.errors import Unsatisfiable

from conftest import CORNELL, start_api

TOKEN = "fuzz-token"


@pytest.fixture(scope="module")
def api_schema(redis_server, tmp_path_factory):
    proc, base = start_api(redis_server, tmp_path_factory.mktemp("fuzz"), api_tokens=TOKEN,
                           max_upload_bytes=1 << 20, preflight_timeout=20)
    schema = schemathesis.openapi.from_url(f"{base}/openapi.json")
    schema.base_url = base
    yield schema
    assert proc.alive(), proc.log()
    proc.stop()


def test_no_server_errors(api_schema):
    """Every operation, with valid and invalid (negative) inputs generated from the schema.
    (Driven through Hypothesis directly: Schemathesis' pytest plugin does not support this
    pytest version.)"""
    from schemathesis import GenerationMode

    failures: list[str] = []
    statuses: dict[str, set[int]] = {}
    operations = [result.ok() for result in api_schema.get_all_operations()]
    assert len(operations) >= 10
    for operation in operations:
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):
            @given(case=operation.as_strategy(generation_mode=mode))
            @settings(max_examples=12, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))
            def fuzz(case):
                response = case.call(headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
                statuses.setdefault(operation.label, set()).add(response.status_code)
                if response.status_code >= 500:
                    failures.append(f"{case.method} {case.formatted_path} ({mode.name}): "
                                    f"{response.status_code} {response.text[:300]}")
            @given(case=operation.as_strategy(generation_mode=mode))
            @settings(max_examples=25, deadline=None, database=None, derandomize=True,
                      suppress_health_check=list(HealthCheck))
            def fuzz_form_with_a_real_scene(case):
                # The same generated form fields, with a scene the pre-flight accepts, so
                # that the settings themselves are fuzzed past the file checks.
                if not isinstance(case.body, dict):
                    return
                form = {k: v if isinstance(v, str) else json.dumps(v)
                        for k, v in case.body.items() if k not in ("file", "manifest")}
                response = httpx.post(f"{api_schema.base_url}/jobs", data=form,
                                      files={"file": ("cornell.usda", CORNELL.read_bytes())},
                                      headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
                statuses.setdefault("POST /jobs (real scene)", set()).add(response.status_code)
                if response.status_code >= 500:
                    failures.append(f"POST /jobs {form} ({mode.name}): "
                                    f"{response.status_code} {response.text[:300]}")
                elif response.status_code == 201:
                    httpx.delete(f"{api_schema.base_url}/jobs/{response.json()['id']}",
                                 headers={"Authorization": f"Bearer {TOKEN}"})

            if operation.label == "POST /jobs":
                fuzz_form_with_a_real_scene()
            try:
                fuzz()
            except Unsatisfiable:
                # No input of this operation can violate its schema (e.g. no parameters).
                assert mode is GenerationMode.NEGATIVE, operation.label
    assert not failures, "\n".join(failures)
    print(statuses)
    # The fuzzing reached past validation: some jobs were queued, some inputs refused.
    # (Which refusals the 12 generated forms meet depends on the schema's fields; a file
    # of the wrong kind is refused with 400 before any field is read, checked directly.)
    assert 422 in statuses["POST /jobs"], statuses
    wrong_kind = httpx.post(f"{api_schema.base_url}/jobs", files={"file": ("scene.txt", b"not usd")},
                            headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60)
    assert wrong_kind.status_code == 400, wrong_kind.text
    assert {201, 422} <= statuses["POST /jobs (real scene)"], statuses
    assert len(statuses) == len(operations) + 1


def test_schema_documents_every_route(api_schema):
    spec = httpx.get(f"{api_schema.base_url}/openapi.json").json()
    paths = set(spec["paths"])
    assert {"/jobs", "/jobs/{job_id}", "/jobs/{job_id}/events", "/jobs/{job_id}/log",
            "/jobs/{job_id}/pause", "/jobs/{job_id}/resume", "/jobs/{job_id}/image.exr",
            "/jobs/{job_id}/preview.png", "/workers", "/metrics", "/healthz"} <= paths
    assert spec["paths"]["/jobs"]["get"]["responses"]["200"]["content"]["application/json"]
