"""Shared fixtures: real redis-server, real uvicorn and worker subprocesses (no fakes)."""
from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import pytest
import redis

from tessera_base import protocol

from tessera_queue import redis_schema as rdb
from tessera_cli.embedded import free_port, redis_server as _redis_server, stop_processes

REPO = Path(__file__).resolve().parents[1]

# Each pytest process (one per xdist worker: scripts/test.sh runs two) gives itself and the
# farms it starts a temporary folder of their own. A farm sweeps what dead processes left in
# its temporary folder when it starts (docs/farm.md), and a test that kills an API on
# purpose must find the API's leftovers there until its own restart, not see another
# test's farm sweep them first.
TEST_TMPDIR = Path(tempfile.gettempdir()) / f"tessera-tests-{os.getpid()}"
TEST_TMPDIR.mkdir(exist_ok=True)
os.environ["TMPDIR"] = str(TEST_TMPDIR)
tempfile.tempdir = None  # gettempdir() reads TMPDIR again
CORNELL = REPO / "examples" / "cornell" / "cornell.usda"
STARTUP_TIMEOUT = 30.0

# The quick tier is `pytest -m "not slow"` (about a minute): these modules run real farms
# (API, workers, Redis restarts, network namespaces), the bench, the fuzz campaign or
# long statistical renders; a test elsewhere may carry @pytest.mark.slow itself.
SLOW_MODULES = {"test_farm_e2e", "test_farm_lifecycle", "test_farm_resilience", "test_farm_netns",
                "test_farm_openapi", "test_farm_storage", "test_farm_auth", "test_farm_users",
                "test_compare_memory", "test_user_scene_limits", "test_slowloris", "test_bundles_farm",
                "test_packing_farm", "test_bench", "test_fuzz", "test_caustic", "test_compare_integrators",
                "test_integrators", "test_scene_passes",
                # A real worker rendering a job to compare with a local render, 4-9 s each.
                "test_farm_black_image", "test_farm_frames", "test_farm_subdivision", "test_farm_variants",
                "test_farm_motion", "test_farm_camera"}


# Real USD files from outside the project (README, "The external scenes"): they sit beside
# the repository, or where TESSERA_SHARED_SCENES says. A test that reads them carries the
# `shared_scenes` mark; without the folder it is skipped (one summary line names the
# folder), unless TESSERA_REQUIRE_SHARED_SCENES=1 (set by .ci/run), which fails it instead
# so that CI cannot lose those tests without a word.
SHARED_SCENES = Path(os.environ.get("TESSERA_SHARED_SCENES", REPO.parent / "shared" / "scenes"))
REQUIRE_SHARED_SCENES = os.environ.get("TESSERA_REQUIRE_SHARED_SCENES") == "1"


def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.module.__name__.rsplit(".", 1)[-1] in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)


def require_shared_scenes() -> Path:
    """The external scenes folder; skips the test without it (fails it under
    TESSERA_REQUIRE_SHARED_SCENES=1). For fixtures; tests carry the `shared_scenes` mark."""
    if not SHARED_SCENES.is_dir():
        message = f"needs the external scenes folder {SHARED_SCENES} (README: the external scenes)"
        if REQUIRE_SHARED_SCENES:
            pytest.fail(f"{message}; TESSERA_REQUIRE_SHARED_SCENES=1 makes its absence a failure",
                        pytrace=False)
        pytest.skip(message)
    return SHARED_SCENES


def pytest_sessionfinish(session, exitstatus):
    # Kept after a failure: the farms' logs and leftovers are what one reads then.
    if exitstatus == 0:
        shutil.rmtree(TEST_TMPDIR, ignore_errors=True)


def pytest_runtest_setup(item):
    if item.get_closest_marker("shared_scenes") is not None:
        require_shared_scenes()


@pytest.fixture(scope="session")
def cornell_path() -> Path:
    """The bundled example scene."""
    return CORNELL


# The data directory (TESSERA_DATA_DIR) every API and worker of this test session shares,
# as one machine's do; each Redis server's farm keeps its own folder in it (data_store).
DATA_ROOT = Path(tempfile.mkdtemp(prefix="tessera-test-data-"))
atexit.register(shutil.rmtree, DATA_ROOT, True)
os.environ["TESSERA_DATA_DIR"] = str(DATA_ROOT)  # for the stores tests make in-process


def clean_env(**extra: str) -> dict[str, str]:
    """The test's environment without any Redis or Tessera settings of the developer's
    (but the session's data directory)."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("TESSERA_") and k != "REDIS_URL"}
    env["PYTHONUNBUFFERED"] = "1"
    env["TESSERA_DATA_DIR"] = str(DATA_ROOT)
    env.update(extra)
    return env


class Process:
    """A subprocess whose output goes to a log file, shown when something fails."""

    def __init__(self, name: str, cmd: list[str], log_dir: Path, env: dict[str, str]):
        self.name = name
        self.log_path = log_dir / f"{name}.log"
        self._log = open(self.log_path, "wb")
        self.popen = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL,
                                      stdout=self._log, stderr=subprocess.STDOUT)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log(self, lines: int = 40) -> str:
        text = self.log_path.read_text(errors="replace").splitlines()
        return f"--- {self.name} (exit {self.popen.poll()}) ---\n" + "\n".join(text[-lines:])

    def stop(self, timeout: float = 10.0) -> None:
        stop_processes([self.popen], timeout)
        self._log.close()


def chromium_driver(*extra_args: str):
    """Debian's chromium, headless, driven by selenium (a real browser for web pages), with
    `extra_args` added to its command line. The caller quits it."""
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is in the test extras")
    chromium, chromedriver = "/usr/bin/chromium", "/usr/bin/chromedriver"
    assert shutil.which(chromium) and shutil.which(chromedriver), (
        "the browser tests need Debian's chromium and chromium-driver (scripts/setup.sh)")
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu",
                "--window-size=1280,1400", "--no-first-run", *extra_args):
        options.add_argument(arg)
    return webdriver.Chrome(options=options, service=webdriver.ChromeService(executable_path=chromedriver))


@pytest.fixture(scope="module")
def browser():
    """Debian's chromium, headless, driven by selenium (a real browser for web pages)."""
    driver = chromium_driver("--force-color-profile=srgb")
    yield driver
    driver.quit()


@pytest.fixture(scope="module")
def redis_server(tmp_path_factory) -> str:
    """URL of a fresh redis-server (free port, no persistence) for the test module."""
    with _redis_server(str(tmp_path_factory.mktemp("redis"))) as local:
        yield local.url


@pytest.fixture(scope="module")
def redis_client(redis_server) -> redis.Redis:
    client = redis.Redis.from_url(redis_server)
    yield client
    client.close()


@contextlib.contextmanager
def api_client(redis_url: str, log_dir: Path):
    """An API process on `redis_url` with no workers of its own, and an httpx client for
    it carrying `.api` (the process), `.redis_url` and `.log_dir` (for the tests' own
    start_worker calls). The process stops when the block ends."""
    api_proc, base = start_api(redis_url, log_dir)
    try:
        with httpx.Client(base_url=base, timeout=60) as client:
            client.api = api_proc
            client.redis_url, client.log_dir = redis_url, log_dir
            yield client
    finally:
        api_proc.stop()


def start_api(redis_url: str, log_dir: Path, host: str = "127.0.0.1",
              cmd_prefix: list[str] = (), public_host: str | None = None,
              **settings: str) -> tuple[Process, str]:
    """uvicorn serving tessera_service on a free port; settings become TESSERA_* variables.
    `cmd_prefix` wraps the command (e.g. ip netns exec NS); `public_host` is where this
    process reaches it (default: host). Returns once /healthz answers. Without api_tokens
    the API serves loopback requests anonymously, as `tessera serve` does locally (unless
    allow_anonymous_loopback says otherwise)."""
    if "api_tokens" not in settings:
        settings.setdefault("allow_anonymous_loopback", "1")
    port = free_port()
    env = clean_env(TESSERA_REDIS_URL=redis_url,
                    **{f"TESSERA_{k.upper()}": str(v) for k, v in settings.items()})
    proc = Process(f"api-{port}", [*cmd_prefix, sys.executable, "-m", "uvicorn", "--factory",
                                   "tessera_service.app:create_app", "--host", host,
                                   "--port", str(port), "--log-level", "warning"], log_dir, env)
    base = f"http://{public_host or host}:{port}"
    wait_until_ready(proc, base)
    return proc, base


def wait_until_ready(proc: Process, base: str) -> None:
    """Returns once the API at `base` answers /healthz with 200; fails with its log if the
    process exits or STARTUP_TIMEOUT passes first."""
    deadline = time.monotonic() + STARTUP_TIMEOUT
    while True:
        assert proc.alive(), "the API exited at startup\n" + proc.log()
        try:
            if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, "the API did not become ready\n" + proc.log()
        time.sleep(0.05)


def start_worker(redis_url: str, name: str, log_dir: Path, heartbeat_ttl: float = 2.0,
                 faults: str = "", tile_timeout: float = 60.0,
                 memory_limit: int = 8 << 30, cmd_prefix: list[str] = (),
                 watch_url: str | None = None) -> Process:
    """A worker process; returns once its heartbeat is in Redis (seen through watch_url,
    default redis_url). `faults`: the worker's fault-injection rules (TESSERA_WORKER_FAULTS)."""
    proc = Process(name, [*cmd_prefix, sys.executable, "-m", "tessera_worker", "--name", name,
                          "--threads", "1", "--heartbeat-ttl", str(heartbeat_ttl),
                          "--tile-timeout", str(tile_timeout),
                          "--memory-limit", str(memory_limit), "--log-level", "DEBUG"],
                   log_dir, clean_env(REDIS_URL=redis_url, TESSERA_WORKER_FAULTS=faults))
    client = redis.Redis.from_url(watch_url or redis_url)
    deadline = time.monotonic() + STARTUP_TIMEOUT
    try:
        while not client.exists(rdb.worker_key(name)):
            assert proc.alive(), f"worker {name} exited at startup\n" + proc.log()
            assert time.monotonic() < deadline, f"worker {name} did not start\n" + proc.log()
            time.sleep(0.05)
    finally:
        client.close()
    return proc


def submit(client: httpx.Client, scene: Path, **form) -> httpx.Response:
    with open(scene, "rb") as f:
        return client.post("/jobs", files={"file": (scene.name, f)},
                           data={k: str(v) for k, v in form.items()})


def wait_for_job(client: httpx.Client, job_id: str, timeout: float = 60.0,
                 processes: list[Process] = (), expect: str | None = None) -> dict:
    """Polls the job until it reaches a final state; returns its last status. With
    `expect`, asserts that state, showing the job's error and the processes' logs if not."""
    deadline = time.monotonic() + timeout
    while True:
        r = client.get(f"/jobs/{job_id}")
        assert r.status_code == 200, r.text
        status = r.json()
        if status["state"] in protocol.FINAL_STATES:
            assert expect is None or status["state"] == expect, (
                f"job {job_id} is {status['state']}, not {expect}: {status.get('error')}\n"
                f"{status}\n" + "\n".join(p.log() for p in processes))
            return status
        assert time.monotonic() < deadline, (
            f"job {job_id} not finished after {timeout} s: {status}\n"
            + "\n".join(p.log() for p in processes))
        time.sleep(0.05)


# ------------------------------------------------------------------ shared test helpers
def local_reference(form: dict):
    """The image `tessera render` makes locally for these job settings."""
    from tessera.local import render_image
    from tessera_base.protocol import RenderSettings
    from tessera_renderer import load_scene

    settings = RenderSettings(**{k: v for k, v in form.items() if k != "priority"})
    return render_image(load_scene(str(CORNELL)), settings, threads=0, progress=False,
                        variance=False).rgba


def farm_image(client: httpx.Client, job_id: str, tmp_path: Path):
    """Downloads a done job's EXR and reads it back."""
    from tessera_base import images

    r = client.get(f"/jobs/{job_id}/image.exr")
    assert r.status_code == 200, r.text
    path = tmp_path / f"{job_id}.exr"
    path.write_bytes(r.content)
    return images.read_exr(path)


def child_pids(pid: int) -> list[int]:
    """Processes whose parent is `pid` (from /proc)."""
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path("/proc", entry, "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def is_running(pid: int) -> bool:
    """True while `pid` exists and is not a zombie."""
    try:
        state = Path("/proc", str(pid), "stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"
