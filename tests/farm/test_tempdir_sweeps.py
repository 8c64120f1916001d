"""Temporary folders of killed processes (issue 42, item 10), with real processes: a
worker's render process killed mid-job (a cancelled job, a tile timeout) left the texture
folder it had unpacked its scene into (tessera-blob-*), and a SIGKILLed `tessera serve`
left its folder with the embedded Redis's ACL file (passwords). Each now carries its
owner's pid and is removed once that process is gone; a live process's folder stays (the
control in each test)."""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import pytest

from conftest import STARTUP_TIMEOUT, clean_env
from tessera_cli.embedded import free_port
from tessera_worker.child import RenderChild


def _folder(kind: str, pid: int) -> Path:
    path = Path(tempfile.mkdtemp(prefix=f"tessera-{kind}-{pid}-"))
    (path / "secret").write_text("x")
    return path


def test_killing_a_render_process_removes_its_texture_folder():
    child = RenderChild(memory_limit=0)
    child.ensure_started()  # a real render process, greeted
    dead = _folder("blob", child.proc.pid)  # what it makes loading a textured scene
    live = _folder("blob", os.getpid())
    try:
        child.kill()  # as for a cancelled job's tile
        assert not dead.exists()
        assert live.is_dir()
    finally:
        child.kill()
        shutil.rmtree(dead, ignore_errors=True)
        shutil.rmtree(live, ignore_errors=True)


@pytest.mark.slow  # two embedded farms (Redis, a worker, the API): 5 s
def test_tessera_serve_removes_what_a_killed_serve_left(tmp_path):
    port = free_port()
    cmd = [sys.executable, "-m", "tessera", "serve", "--port", str(port), "--workers", "1"]
    log = open(tmp_path / "serve.log", "wb")
    first = subprocess.Popen(cmd, env=clean_env(), stdout=log, stderr=subprocess.STDOUT,
                             start_new_session=True)
    mine = None
    try:
        _wait_ready(port, first, tmp_path)
        [left] = Path(tempfile.gettempdir()).glob(f"tessera-serve-{first.pid}-*")
        assert (left / "users.acl").is_file()
        os.killpg(first.pid, signal.SIGKILL)  # (its Redis and worker follow: PDEATHSIG)
        first.wait()
        assert (left / "users.acl").is_file()  # what the kill leaves
        live = _folder("serve", os.getpid())  # the control: a live owner's folder
        second = subprocess.Popen(cmd, env=clean_env(), stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        try:
            _wait_ready(port, second, tmp_path)
            assert not left.exists()
            assert live.is_dir()
            assert f"removed {left}" in (tmp_path / "serve.log").read_text(errors="replace")
        finally:
            second.send_signal(signal.SIGINT)
            second.wait(timeout=60)
            shutil.rmtree(live, ignore_errors=True)
        assert not list(Path(tempfile.gettempdir()).glob(f"tessera-serve-{second.pid}-*"))
    finally:
        if first.poll() is None:
            os.killpg(first.pid, signal.SIGKILL)
            first.wait()
        log.close()


def _wait_ready(port: int, proc: subprocess.Popen, tmp_path: Path) -> None:
    deadline = time.monotonic() + STARTUP_TIMEOUT
    while True:
        assert proc.poll() is None, (tmp_path / "serve.log").read_text(errors="replace")
        try:
            if httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, (tmp_path / "serve.log").read_text(errors="replace")
        time.sleep(0.05)
