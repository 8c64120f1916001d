"""The Redis start commands of deploy/docker-compose.yml and deploy/k8s/redis.yaml, run
for real: the same shell command line, with this machine's redis-server, the repository's
redis.conf and users.acl where the image has them (/opt/tessera), and only the port, the
data directory and the listening address overridden (a free loopback port, a temporary
directory). Then the health checks of compose and Kubernetes, and a worker and its probe
authenticated as the ACL users with the passwords the command filled in."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import redis
import yaml

from conftest import clean_env, start_worker
from tessera_cli.embedded import free_port

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"
PASSWORDS = {"REDIS_API_PASSWORD": "a1" * 32, "REDIS_WORKER_PASSWORD": "b2" * 32}


def compose_redis() -> dict:
    return yaml.safe_load((DEPLOY / "docker-compose.yml").read_text())["services"]["redis"]


def k8s_redis() -> dict:
    docs = yaml.safe_load_all((DEPLOY / "k8s" / "redis.yaml").read_text())
    (sts,) = [d for d in docs if d["kind"] == "StatefulSet"]
    (container,) = sts["spec"]["template"]["spec"]["containers"]
    return container


def local_script(script: str, tmp: Path, acl_in_image: str, port: int) -> str:
    """The command as this machine runs it: the image's paths mapped to the repository's.
    redis.conf is copied with its `dir` (the image's volume) set to `tmp`: Redis enters
    that directory while it reads the file, before any command-line option applies."""
    conf = (DEPLOY / "redis.conf").read_text()
    lines = [f"dir {tmp}" if line.startswith("dir ") else line for line in conf.splitlines()]
    assert lines != conf.splitlines()
    (tmp / "redis.conf").write_text("\n".join(lines) + "\n")
    # compose's official Redis image keeps its data in /data (--dir): here, `tmp`.
    script = (script.replace("--dir /data", f"--dir {tmp}")
              .replace("/opt/tessera/deploy/redis.conf", str(tmp / "redis.conf"))
              .replace("/opt/tessera/", f"{REPO}/").replace(acl_in_image, str(tmp / "users.acl")))
    assert "/opt/tessera" not in script and str(tmp / "redis.conf") in script
    return script + f" --port {port} --bind 127.0.0.1"


class RedisFromDeploy:
    """The deploy command's redis-server, on a free loopback port."""

    def __init__(self, kind: str, script: str, acl_in_image: str, tmp: Path):
        self.kind, self.tmp, self.port = kind, tmp, free_port()
        self.log = open(tmp / "redis.log", "wb")
        self.proc = subprocess.Popen(["sh", "-c", local_script(script, tmp, acl_in_image, self.port)],
                                     env=clean_env(**PASSWORDS), stdout=self.log,
                                     stderr=subprocess.STDOUT)

    def url(self, user: str, password: str) -> str:
        return f"redis://{user}:{password}@127.0.0.1:{self.port}/0"

    def wait_ready(self) -> None:
        client = redis.Redis.from_url(self.url("tessera-api", PASSWORDS["REDIS_API_PASSWORD"]))
        deadline = time.monotonic() + 30
        while True:
            assert self.proc.poll() is None, (self.tmp / "redis.log").read_text()
            try:
                if client.ping():
                    return
            except redis.ConnectionError:
                pass
            assert time.monotonic() < deadline, (self.tmp / "redis.log").read_text()
            time.sleep(0.05)

    def stop(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=30)
        self.log.close()


@pytest.fixture(params=["compose", "kubernetes"])
def deployed_redis(request, tmp_path):
    if request.param == "compose":
        spec = compose_redis()
        script = " ".join(spec["command"]).replace("$$", "$")  # compose's escape
        acl = "/tmp/tessera-users.acl"
    else:
        script = " ".join(k8s_redis()["args"])
        acl = "/run/tessera/users.acl"
    server = RedisFromDeploy(request.param, script, acl, tmp_path)
    try:
        server.wait_ready()
        yield server
    finally:
        server.stop()


def healthcheck_command(server) -> str:
    if server.kind == "compose":
        test = compose_redis()["healthcheck"]["test"]
        assert test[0] == "CMD-SHELL"
        command = test[1].replace("$$", "$")
    else:
        command = k8s_redis()["readinessProbe"]["exec"]["command"]
        assert command[:2] == ["sh", "-c"]
        command = command[2]
    return command.replace("redis-cli", f"redis-cli -p {server.port}")


def test_the_acl_users_get_the_passwords_and_nobody_else_gets_in(deployed_redis):
    server = deployed_redis
    api = redis.Redis.from_url(server.url("tessera-api", PASSWORDS["REDIS_API_PASSWORD"]))
    worker = redis.Redis.from_url(server.url("tessera-worker", PASSWORDS["REDIS_WORKER_PASSWORD"]))
    assert api.ping() and worker.ping()
    # A write is in the append-only file when its reply arrives (appendfsync always).
    assert api.set("tessera:probe", "persisted-value")
    aof = b"".join(f.read_bytes() for f in (server.tmp / "appendonlydir").iterdir())
    assert b"persisted-value" in aof
    for url in (server.url("tessera-api", "CHANGE-ME-api-password"),
                server.url("tessera-worker", PASSWORDS["REDIS_API_PASSWORD"]),
                f"redis://127.0.0.1:{server.port}/0"):
        with pytest.raises((redis.AuthenticationError, redis.ResponseError)):
            redis.Redis.from_url(url).set("tessera:probe", "2")
    # The ACL written for Redis is readable by its owner only (umask 077).
    assert oct((server.tmp / "users.acl").stat().st_mode & 0o777) == "0o600"


def test_health_checks_pass_and_fail_with_the_password(deployed_redis):
    command = healthcheck_command(deployed_redis)
    ok = subprocess.run(["sh", "-c", command], env=clean_env(**PASSWORDS), capture_output=True)
    assert ok.returncode == 0, ok
    # Negative control: the same check with a wrong password fails.
    wrong = clean_env(**{**PASSWORDS, "REDIS_API_PASSWORD": "c3" * 32})
    bad = subprocess.run(["sh", "-c", command], env=wrong, capture_output=True)
    assert bad.returncode != 0


@pytest.mark.slow
@pytest.mark.parametrize("deployed_redis", ["compose"], indirect=True)
def test_worker_probe_works_as_the_worker_acl_user(deployed_redis, tmp_path):
    url = deployed_redis.url("tessera-worker", PASSWORDS["REDIS_WORKER_PASSWORD"])
    worker = start_worker(url, "acl-w", tmp_path)
    try:
        probe = subprocess.run([sys.executable, "-m", "tessera_worker.probe"],
                               env=clean_env(REDIS_URL=url), capture_output=True, text=True,
                               timeout=60)
        assert probe.returncode == 0, probe.stdout + probe.stderr
        assert "acl-w" in probe.stdout
    finally:
        worker.stop()
