"""A whole farm in one command: a private Redis, local workers and the API.

serve() without a redis_url starts `redis-server` on a free local port (no persistence,
in a temporary directory, with the farm's data directory beside it) and `workers` worker
processes, runs the API in this process,
and stops them all when the API stops (Ctrl-C / SIGTERM). With a redis_url only the API
runs; workers are started elsewhere against the same Redis."""
from __future__ import annotations

import logging
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from urllib.parse import urlsplit

import redis

from tessera_base.process import die_with_parent, remove_orphaned_tempdirs

from tessera_service.redis_acl import API_USER, WORKER_USER, Credentials, acl_file

log = logging.getLogger("tessera.serve")

WORKER_COMMAND = [sys.executable, "-m", "tessera_cli", "worker"]
WORKER_STOP_TIMEOUT = 30.0  # seconds a worker may take to finish its tile on shutdown


def serve(host: str = "127.0.0.1", port: int = 8000, workers: int = 1,
          redis_url: str | None = None, *, worker_threads: int = 1,
          log_level: str = "info", insecure_local: bool | None = None) -> None:
    """Runs the API on host:port until interrupted. See the module docstring.

    `insecure_local`: serve this machine's users without tokens when no TESSERA_API_TOKENS
    are set (Settings.allow_anonymous_loopback). None: yes for the embedded farm on a
    loopback address (a private single-machine farm), no when serving an existing Redis
    (a deployment, which needs tokens or this set explicitly)."""
    import uvicorn

    from tessera_service.app import create_app
    from tessera_service.http_guard import connection_cap, guarded_protocol
    from tessera_service.settings import Settings

    # Uvicorn handles SIGINT/SIGTERM while it runs and re-raises the signal once it has
    # stopped; this handler absorbs that, so that the workers and Redis are then stopped
    # in order. Outside of uvicorn's run a signal interrupts whatever we are waiting for.
    from tessera_service.auth import is_loopback

    phase = "starting"
    embedded = redis_url is None
    environment = Settings()
    if not is_loopback(host) and not environment.api_tokens:
        raise SystemExit(f"tessera serve: refusing to listen on {host} without authentication: "
                         "set TESSERA_API_TOKENS (comma-separated user:token pairs), or bind to "
                         "127.0.0.1")
    if not embedded and urlsplit(redis_url).password is None:
        log.warning("the Redis URL has no password: give Redis the farm's ACL users "
                    "(deploy/users.acl) and use redis://%s:PASSWORD@HOST:PORT/0", API_USER)
    if insecure_local is None:
        insecure_local = embedded and is_loopback(host)
    anonymous = {}
    if insecure_local and not environment.api_tokens:
        anonymous = {"allow_anonymous_loopback": True}  # said here, never inferred later
        log.warning("no API tokens: serving requests from this machine only, without "
                    "authentication (--insecure-local)")

    def on_signal(signum, frame):
        if phase != "running":
            raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with ExitStack() as stack:
            if embedded:
                # A killed serve left its folder, Redis passwords included: the pid in the
                # name lets the next serve remove it.
                for leftover in remove_orphaned_tempdirs("serve"):
                    log.warning("removed %s, left by a tessera serve that was killed", leftover)
                tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix=f"tessera-serve-{os.getpid()}-"))
                # Password-protected even on loopback: other users of this machine reach
                # 127.0.0.1 too.
                local = stack.enter_context(redis_server(tmp, credentials=Credentials.generate()))
                redis_url = local.url
                log.warning("started a private redis-server on 127.0.0.1:%d (ACL users %s and "
                            "%s; nothing is persisted)", local.port, API_USER, WORKER_USER)
                url = local.worker_url
                # The data store beside Redis, gone with it (nothing is persisted).
                data_dir = os.path.join(tmp, "data")
                supervisor = WorkerSupervisor(lambda: start_worker(url, threads=worker_threads,
                                                                   data_dir=data_dir), workers)
                stack.callback(supervisor.stop, WORKER_STOP_TIMEOUT)
                supervisor.start()
                log.warning("started %d local worker(s)", workers)
            # Tokens etc. come from the environment. Uvicorn's own proxy-header handling
            # is off: it would replace the peer address with a header's value for any
            # request from 127.0.0.1, and AuthGate decides whom to believe.
            app = create_app(Settings(redis_url=redis_url, **anonymous,
                                      **({"data_dir": data_dir} if embedded else {})))
            limits = app.state.settings
            cap = connection_cap(limits.http_max_connections)
            protocol = guarded_protocol(limits.http_header_timeout, limits.http_body_idle_timeout, cap)
            server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level=log_level,
                                                   proxy_headers=False, http=protocol))
            phase = "running"
            server.run()
            phase = "stopping"
            if embedded:
                log.warning("stopping the local worker(s) and redis-server")
    except KeyboardInterrupt:
        log.warning("interrupted")
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


# The embedded Redis's memory limit (bytes): twice the default per-job budget
# (service settings' job_redis_budget), so one job at the budget leaves room for others.
EMBEDDED_REDIS_MAXMEMORY = 2 << 30


@dataclass
class LocalRedis:
    process: subprocess.Popen
    url: str          # the API's (with credentials: as the API user)
    port: int
    worker_url: str   # the workers' (with credentials: as the worker user)


@contextmanager
def redis_server(workdir: str, port: int | None = None, timeout: float = 10.0, *,
                 appendonly: bool = False, bind: str = "127.0.0.1", netns: str | None = None,
                 maxmemory: int = EMBEDDED_REDIS_MAXMEMORY, credentials: Credentials | None = None):
    """A redis-server on `bind` (default: a free port on 127.0.0.1) for the block. Without
    `appendonly` nothing is persisted; with it, an append-only file in workdir is fsynced
    on every write (as deploy/redis.conf does), so a restart in the same workdir resumes
    exactly. `netns`: run it inside that network namespace (ip netns exec). `maxmemory`
    bytes with noeviction, as deploy/redis.conf: a full Redis refuses writes (workers
    keep their tile and retry) and never drops accepted work. `credentials`: the farm's
    ACL users (redis_acl) with these passwords, the default user off; without, anyone who
    reaches the port may do anything (for tests)."""
    exe = shutil.which("redis-server")
    if exe is None:
        raise RuntimeError("redis-server is not installed (apt-get install redis-server), "
                           "or pass a Redis URL")
    port = port or free_port()
    logfile = os.path.join(workdir, "redis.log")
    persistence = (["--appendonly", "yes", "--appendfsync", "always"] if appendonly
                   else ["--appendonly", "no"])
    prefix = ["ip", "netns", "exec", netns] if netns else []
    if credentials is not None:
        aclfile = os.path.join(workdir, "users.acl")
        # Passwords go in a file only we can read, never on a command line (ps shows those).
        fd = os.open(aclfile, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w") as f:
            f.write(acl_file(credentials.api_password, credentials.worker_password))
        access = ["--aclfile", aclfile, "--protected-mode", "yes"]
        url = credentials.url(API_USER, bind, port)
        worker_url = credentials.url(WORKER_USER, bind, port)
    else:
        access = ["--protected-mode", "no"]
        url = worker_url = f"redis://{bind}:{port}/0"
    proc = subprocess.Popen(
        [*prefix, exe, "--port", str(port), "--bind", bind, "--save", "", *persistence,
         "--maxmemory", str(maxmemory), "--maxmemory-policy", "noeviction",
         *access, "--dir", workdir, "--logfile", logfile, "--daemonize", "no"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
        start_new_session=True, preexec_fn=die_with_parent)
    try:
        client = redis.Redis.from_url(url, socket_connect_timeout=1)
        deadline = time.monotonic() + timeout
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"redis-server exited with code {proc.returncode}: "
                                   + _tail(logfile))
            try:
                client.ping()
                break
            except redis.ConnectionError:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"redis-server did not answer within {timeout:g} s: "
                                       + _tail(logfile)) from None
                time.sleep(0.05)
        client.close()
        yield LocalRedis(proc, url, port, worker_url)
    finally:
        stop_processes([proc], 10.0)


class WorkerSupervisor:
    """Keeps `count` worker processes alive: a worker that dies (a crash, the OOM killer,
    a SIGKILL) is reaped at once and started again, after a delay that doubles while
    workers keep dying young (RESTART_DELAY up to MAX_RESTART_DELAY) and resets once one
    has lived HEALTHY_LIFETIME. Without it a killed embedded worker stayed a zombie and its
    job never finished."""

    RESTART_DELAY, MAX_RESTART_DELAY, HEALTHY_LIFETIME = 0.5, 30.0, 60.0
    POLL = 0.2

    def __init__(self, start, count: int):
        self._start = start
        self._slots: list[dict] = [{"proc": None, "since": 0.0, "due": 0.0, "delay": self.RESTART_DELAY}
                                   for _ in range(count)]
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="worker-supervisor", daemon=True)
        self.restarts = 0

    def start(self) -> None:
        with self._lock:
            for slot in self._slots:
                self._launch(slot)
        self._thread.start()

    @property
    def processes(self) -> list[subprocess.Popen]:
        with self._lock:
            return [s["proc"] for s in self._slots if s["proc"] is not None]

    def _launch(self, slot: dict) -> None:
        slot["proc"], slot["since"] = self._start(), time.monotonic()

    def _run(self) -> None:
        while not self._stop.wait(self.POLL):
            with self._lock:
                for slot in self._slots:
                    self._check(slot)

    def _check(self, slot: dict) -> None:
        now, proc = time.monotonic(), slot["proc"]
        if proc is not None:
            code = proc.poll()  # reaps it: no zombie
            if code is None:
                if now - slot["since"] >= self.HEALTHY_LIFETIME:
                    slot["delay"] = self.RESTART_DELAY
                return
            lived = now - slot["since"]
            if lived < self.HEALTHY_LIFETIME and slot["due"]:
                slot["delay"] = min(self.MAX_RESTART_DELAY, slot["delay"] * 2)
            slot["proc"], slot["due"] = None, now + slot["delay"]
            log.warning("worker pid %d exited with code %s after %.1f s; restarting it in %.1f s",
                        proc.pid, code, lived, slot["delay"])
        if now >= slot["due"] and not self._stop.is_set():
            self._launch(slot)
            self.restarts += 1
            log.warning("restarted a local worker (pid %d)", slot["proc"].pid)

    def stop(self, timeout: float) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        stop_processes(self.processes, timeout)


def start_worker(redis_url: str, threads: int = 1, name: str | None = None,
                 command: list[str] | None = None, data_dir: str | None = None) -> subprocess.Popen:
    """A worker process (in its own session, so that the terminal's Ctrl-C reaches only us
    and we stop workers before Redis); `data_dir`: the API's data directory (default: the
    environment's)."""
    cmd = list(command or WORKER_COMMAND) + ["--threads", str(threads)]
    if name:
        cmd += ["--name", name]
    env = {**os.environ, "REDIS_URL": redis_url}
    if data_dir is not None:
        env["TESSERA_DATA_DIR"] = data_dir
    return subprocess.Popen(cmd, env=env,
                            stdin=subprocess.DEVNULL, start_new_session=True,
                            preexec_fn=die_with_parent)


def stop_processes(procs: list[subprocess.Popen], timeout: float) -> None:
    """SIGTERM, then SIGKILL whatever has not exited after timeout seconds."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            log.warning("process %d did not stop within %g s; killing it", p.pid, timeout)
            p.kill()
            p.wait()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]




def _tail(path: str, lines: int = 5) -> str:
    try:
        with open(path, errors="replace") as f:
            return " | ".join(f.read().splitlines()[-lines:])
    except OSError:
        return "(no log)"
