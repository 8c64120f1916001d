"""Rendering a reference on a farm (`tessera refs create|update --farm URL`): the job asks
for the variance and spp AOVs, so the farm's EXR carries the same noise estimate and
metadata as a local render, channel for channel (tests/test_farm_e2e.py,
tests/test_refs_farm.py)."""
from __future__ import annotations

import json
import time
from pathlib import Path

from .refs import Reference, RefsError

POLL_SECONDS = 0.5
FINAL = ("done", "failed", "cancelled")


def job_form(ref: Reference) -> dict[str, str]:
    """The POST /jobs form fields of a reference's render."""
    form = dict(width=ref.width, height=ref.height, seed=ref.seed, max_depth=ref.max_depth,
                integrator=ref.integrator, aovs="variance,spp")
    if ref.target_error is None:
        form["spp"] = ref.spp
    else:
        form.update(target_error=ref.target_error, max_spp=ref.spp)
    if ref.integrator_params:
        form["integrator_params"] = json.dumps(ref.integrator_params)
    return {k: str(v) for k, v in form.items()}


def render_on_farm(url: str, token: str | None, scene: Path, ref: Reference, out: Path,
                   timeout: float = 24 * 3600) -> None:
    """Submits `scene`, waits for the job and downloads its EXR to `out`; RefsError when
    the farm refuses, fails or cannot be reached."""
    import httpx

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        with httpx.Client(base_url=url.rstrip("/"), headers=headers,
                          timeout=httpx.Timeout(60, read=None)) as client:
            with open(scene, "rb") as f:
                r = client.post("/jobs", files={"file": (scene.name, f)}, data=job_form(ref))
            if r.status_code != 201:
                raise RefsError(f"reference {ref.name}: the farm refused the job ({r.status_code}): "
                                f"{r.text[:300]}")
            job = r.json()["id"]
            deadline = time.monotonic() + timeout
            while (status := client.get(f"/jobs/{job}").json())["state"] not in FINAL:
                if time.monotonic() > deadline:
                    raise RefsError(f"reference {ref.name}: job {job} not done after {timeout:g} s")
                time.sleep(POLL_SECONDS)
            if status["state"] != "done":
                raise RefsError(f"reference {ref.name}: job {job} {status['state']}: "
                                f"{status.get('error') or ''}")
            r = client.get(f"/jobs/{job}/image.exr")
            if r.status_code != 200:
                raise RefsError(f"reference {ref.name}: cannot download job {job}'s image: {r.text[:300]}")
            out.write_bytes(r.content)
    except httpx.HTTPError as exc:
        raise RefsError(f"reference {ref.name}: cannot talk to the farm at {url}: {exc}") from None
