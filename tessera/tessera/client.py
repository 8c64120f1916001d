"""`tessera.Client`: a Tessera farm over its HTTP API (docs/farm.md), from Python.

    with tessera.Client("http://farm:8000", token="TOKEN") as farm:
        job = farm.submit("scene.usda", spp=64, integrator="bdpt", res=(256, 256))
        for event in farm.events(job.id):   # until the job's final state
            print(event.type, event.tiles_done)
        image = farm.download(job.id)       # a tessera.Image, equal to tessera.render's
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Mapping

import httpx

from .rendering import Image

if TYPE_CHECKING:  # the event model is the queue layer's (tessera_queue.redis_schema)
    from tessera_queue.redis_schema import JobEvent

FINAL_STATES = ("done", "failed", "cancelled")


class FarmError(RuntimeError):
    """The farm refused a request or could not be reached; `status_code` is the HTTP
    status (None when there was no answer) and the message is the server's detail."""

    def __init__(self, message: str, status_code: int | None = None, detail: str | None = None):
        super().__init__(message)
        self.status_code = status_code
        self.detail = detail if detail is not None else message


@dataclass
class Job:
    """What the farm says about one job (GET /jobs/ID; the answer of POST /jobs has the
    fields it knows then). `raw` is the whole JSON answer."""

    id: str
    state: str
    tiles_total: int
    tiles_done: int = 0
    warnings: list[str] = field(default_factory=list)
    error: str | None = None
    elapsed_seconds: float | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    # A frame range (submitted with frames=): frame -> that frame's job id, in order.
    frames: dict[int, str] | None = None

    @property
    def finished(self) -> bool:
        return self.state in FINAL_STATES

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "Job":
        return cls(id=data["id"], state=data["state"], tiles_total=data["tiles_total"],
                   tiles_done=data.get("tiles_done", 0), warnings=list(data.get("warnings", [])),
                   error=data.get("error"), elapsed_seconds=data.get("elapsed_seconds"), raw=data,
                   frames=({int(f["frame"]): f["job"] for f in data["frames"]}
                           if data.get("frames") is not None else None))


class Client:
    """A farm's HTTP API at `url`, as user `token` (sent as a bearer token; None for a
    farm that serves this machine anonymously). Use it as a context manager, or close()."""

    def __init__(self, url: str, token: str | None = None, *, timeout: float = 60.0):
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        # No read timeout: an event stream stays open as long as the job runs.
        self._http = httpx.Client(base_url=url.rstrip("/"), headers=headers,
                                  timeout=httpx.Timeout(timeout, read=None))
        self.url = url

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    # -- jobs ---------------------------------------------------------------------------
    def submit(self, scene: str | Path, *, spp: int | None = None, integrator: str | None = None,
               res: tuple[int, int] | None = None, aovs: Iterable[str] = (), seed: int | None = None,
               priority: int | None = None, integrator_params: Mapping[str, float] | None = None,
               report: Callable[[str], None] | None = None, **settings: Any) -> Job:
        """Uploads `scene` as a new job and returns it (state "queued"). A .zip/.usdz bundle
        is sent as it is; a loose USD layer travels with its assets: its dependencies are
        gathered (tessera_renderer.usd.packing) and only the files the farm lacks are
        uploaded (tessera.upload), and `report` (if given) receives one line per file that
        could not be packed and a summary of what was sent. A layer that cannot be read
        here is sent alone, so that the farm's pre-flight says why. The keywords are
        tessera.render's; `priority` is 0-9 and any other job setting of POST /jobs
        (max_depth, tile_size, target_error, min_spp, max_spp, time_limit, max_attempts,
        default_light, denoise, crop, camera, subdivision_level, frame, shutter as (open,
        close), frames as "1-24x2", variants as ["/Car:wheels=sedan", ...]) passes through
        `settings`; with frames, the Job is the
        frame range's (Job.frames lists each frame's job)."""
        form: dict[str, Any] = dict(spp=spp, integrator=integrator, seed=seed, priority=priority, **settings)
        if res is not None:
            form["width"], form["height"] = res
        aovs = list(aovs)
        if aovs:
            form["aovs"] = ",".join(aovs)
        if integrator_params:
            form["integrator_params"] = json.dumps(dict(integrator_params))
        def text(v: Any) -> str:  # the API's form: booleans in lower case, pairs as A,B (shutter)
            if isinstance(v, bool):
                return str(v).lower()
            return ",".join(map(str, v)) if isinstance(v, (tuple, list)) else str(v)

        data = {k: text(v) for k, v in form.items() if v is not None}
        r = self._post_scene(Path(scene), data, report or (lambda line: None))
        if r.status_code >= 400:
            raise FarmError(f"POST /jobs: {r.status_code}: {_detail(r)}", r.status_code, _detail(r))
        return Job.from_json(r.json())

    def _post_scene(self, scene: Path, form: dict[str, str], report: Callable[[str], None]) -> httpx.Response:
        def send_alone() -> httpx.Response:
            with open(scene, "rb") as f:
                return self._send("POST", "/jobs", files={"file": (scene.name, f)}, data=form)

        if scene.suffix.lower() in (".usdz", ".zip"):
            return send_alone()
        from tessera_renderer import SceneError
        from tessera_renderer.usd.packing import gather

        from .upload import submit_packed

        try:
            pack = gather(scene)
        except SceneError as exc:
            if not scene.is_file():
                raise ValueError(str(exc)) from None
            report(f"warning: not packed, sent alone: {exc}")
            return send_alone()
        for line in pack.missing:
            report(f"warning: not found, not packed: {line}")
        for line in pack.unportable:
            report(f"warning: cannot travel: {line}")
        try:
            r, sent = submit_packed(self._http, pack.files, pack.entry, form)
        except httpx.HTTPError as exc:
            raise FarmError(f"cannot talk to {self.url}: {exc}") from None
        report(f"{scene.name}: {sent.summary()} (from {pack.root})")
        return r

    def health(self) -> dict[str, Any]:
        """GET /healthz: the farm's state (ok or degraded, its workers); FarmError when it
        cannot be reached or its job store is down. Needs no token."""
        return self._request("GET", "/healthz").json()

    def status(self, job_id: str) -> Job:
        """The job's state, progress, timings, warnings and error."""
        return Job.from_json(self._request("GET", f"/jobs/{job_id}").json())

    def events(self, job_id: str, *, after: str | None = None) -> Iterator["JobEvent"]:
        """The job's progress events (tessera_queue.redis_schema.JobEvent: state, tile,
        pass, scene_pass, failure), from the first (or after event id `after`) until the
        job's final state. A dropped connection is resumed where it stopped."""
        from tessera_queue.redis_schema import JobEvent

        cursor = after
        while True:
            params = {"after": cursor} if cursor else {}
            try:
                with self._http.stream("GET", f"/jobs/{job_id}/events", params=params) as r:
                    if r.status_code != 200:
                        r.read()
                        raise FarmError(_detail(r), r.status_code)
                    for line in r.iter_lines():
                        if line.startswith("id: "):
                            cursor = line[4:]
                        elif line.startswith("data: "):
                            event = JobEvent.model_validate_json(line[6:])
                            yield event
                            if event.type == "state" and event.state in FINAL_STATES:
                                return
            except httpx.TransportError:
                continue  # the connection dropped: resume after the last event seen
            # The server ends a stream without a final event only for a job that has
            # finished (its events trimmed) or expired; status() says which.
            if self.status(job_id).finished:
                return

    def wait(self, job_id: str) -> Job:
        """Follows the job's events until it is done, failed or cancelled; its last status.
        For a frame range, each frame's job in turn, then the sequence's status."""
        status = self.status(job_id)
        for frame_job in (status.frames or {job_id: job_id}).values():
            for _ in self.events(frame_job):
                pass
        return self.status(job_id)

    def download(self, job_id: str, path: str | Path | None = None) -> Image:
        """The finished job's image (the EXR the farm merged) as a tessera.Image; with
        `path`, also written there byte for byte. FarmError 409 while it is not done."""
        r = self._request("GET", f"/jobs/{job_id}/image.exr")
        if path is None:
            import tempfile

            with tempfile.TemporaryDirectory(prefix="tessera-download-") as tmp:
                target = Path(tmp) / f"{job_id}.exr"
                target.write_bytes(r.content)
                return Image.read(target)
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(r.content)
        return Image.read(target)

    def download_frame(self, job_id: str, frame: int, path: str | Path) -> Image:
        """One frame of a frame range, written to `path` and read back."""
        r = self._request("GET", f"/jobs/{job_id}/frames/{frame}/image.exr")
        target = Path(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(r.content)
        return Image.read(target)

    def cancel(self, job_id: str) -> Job:
        """Cancels the job (its queued tiles are dropped); returns its status."""
        return Job.from_json(self._request("DELETE", f"/jobs/{job_id}").json())

    # -- plumbing -----------------------------------------------------------------------
    def _send(self, method: str, path: str, **kwargs) -> httpx.Response:
        try:
            return self._http.request(method, path, **kwargs)
        except httpx.HTTPError as exc:
            raise FarmError(f"cannot talk to {self.url}: {exc}") from None

    def _request(self, method: str, path: str, **kwargs) -> httpx.Response:
        r = self._send(method, path, **kwargs)
        if r.status_code >= 400:
            raise FarmError(f"{method} {path}: {r.status_code}: {_detail(r)}", r.status_code, _detail(r))
        return r


def _detail(response: httpx.Response) -> str:
    try:
        detail = response.json().get("detail")
    except ValueError:
        return response.text[:200]
    if isinstance(detail, list):  # FastAPI's request validation: one line per field, joined
        return "; ".join(_field_problem(e) for e in detail)
    return str(detail)


def _field_problem(error: Any) -> str:
    """One of FastAPI's validation errors ({"loc": ["body", "priority"], "msg": ...,
    "input": ..., "ctx": {"le": 9}}) as `priority: must be <= 9, not '12'`."""
    if not isinstance(error, dict):
        return str(error)
    loc = [str(part) for part in error.get("loc", []) if part not in ("body", "query", "path")]
    ctx = error.get("ctx") or {}
    bounds = [f"{op} {ctx[key]}" for key, op in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<"))
              if key in ctx]
    message = f"must be {' and '.join(bounds)}" if bounds else str(error.get("msg", "invalid"))
    if "input" in error:
        message += f", not {error['input']!r}"
    return f"{'.'.join(loc) or 'request'}: {message}"
