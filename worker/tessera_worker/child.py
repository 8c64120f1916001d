"""The worker's render process (render_child.py) seen from the worker: started on first
use and again after it dies, with an address-space limit; a tile that crashes it, runs
out of memory or time fails that attempt (RenderFailed), and a job that ends meanwhile
abandons it (Abandoned)."""
from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from multiprocessing.connection import Connection

from tessera_base.process import die_with_parent, remove_orphaned_tempdirs

CHILD_START_TIMEOUT = 120.0
CANCEL_POLL = 0.5          # seconds between looks at the job's state during a render


class RenderFailed(Exception):
    """A failed attempt at a tile. `fatal`: the job fails at once (retrying elsewhere
    would fail the same way); otherwise the tile is queued again."""

    def __init__(self, message: str, fatal: bool):
        super().__init__(message)
        self.fatal = fatal


class Abandoned(Exception):
    """The job ended (cancelled or failed elsewhere) while its tile rendered."""


class RenderChild:
    """The render process, started on first use and again after it dies."""

    def __init__(self, memory_limit: int):
        self.memory_limit = memory_limit
        self.proc: subprocess.Popen | None = None
        self.conn: Connection | None = None
        self.serial = 0
        self.blob_version: str | None = None  # the renderer's scene-blob version, if any
        self._greeted = False

    def start(self) -> None:
        parent, child = socket.socketpair()
        limit = self.memory_limit

        def limits() -> None:  # between fork and exec: keep it minimal
            import resource
            if limit > 0:
                resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
            resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
            die_with_parent(signal.SIGKILL)  # no render outlives its worker

        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tessera_worker.render_child", "--fd", str(child.fileno())],
            pass_fds=[child.fileno()], stdin=subprocess.DEVNULL, preexec_fn=limits)
        child.close()
        self.conn = Connection(parent.detach())
        self._greeted = False

    def ensure_started(self) -> None:
        """Starts the child if needed and reads its greeting (which says whether the
        renderer can load translated-scene blobs)."""
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        if self._greeted:
            return
        try:
            ready = self.conn.poll(CHILD_START_TIMEOUT)
            hello = self.conn.recv() if ready else None
        except (EOFError, OSError):
            hello = None
        if not (isinstance(hello, tuple) and len(hello) == 2 and hello[0] == "hello"):
            self.kill()
            raise RenderFailed("the render process failed to start", fatal=False)
        self.blob_version = hello[1]
        self._greeted = True

    def render(self, request: dict, timeout: float, abandoned) -> tuple:
        """Sends one request and waits for its reply. Raises RenderFailed if the child dies
        or exceeds `timeout`, Abandoned if abandoned() becomes true meanwhile (the child is
        then killed, so that a cancelled job stops rendering at once). On any other error
        the child is killed too: a reply must never be read for the wrong request."""
        self.ensure_started()
        self.serial += 1
        request = {**request, "serial": self.serial}
        try:
            self.conn.send(request)
            deadline = time.monotonic() + timeout
            while not self.conn.poll(min(CANCEL_POLL, max(0.0, deadline - time.monotonic()))):
                if self.proc.poll() is not None:
                    break
                if time.monotonic() >= deadline:
                    self.kill()
                    raise RenderFailed(f"exceeded the per-tile time limit of {timeout:g} s",
                                       fatal=True)
                if abandoned():
                    self.kill()
                    raise Abandoned()
            reply = self.conn.recv()
        except (EOFError, OSError):
            code = self.proc.wait()
            self.close()
            if code < 0:
                try:
                    what = signal.Signals(-code).name
                except ValueError:
                    what = f"signal {-code}"
            else:
                what = f"exit code {code}"
            raise RenderFailed(f"the renderer crashed ({what})", fatal=False) from None
        except (RenderFailed, Abandoned):
            raise
        except BaseException:
            self.kill()
            raise
        if reply[-1] != self.serial:
            self.kill()
            raise RenderFailed("the render process answered out of turn", fatal=False)
        return reply[:-1]

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
            # A killed render process (a cancelled job, a timeout) cannot remove the
            # texture folder it unpacked its scene into: it is dead now, so remove it here.
            remove_orphaned_tempdirs("blob")
        self.close()

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.conn = None
        self.proc = None if self.proc is None or self.proc.poll() is not None else self.proc

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.conn.close()  # EOF: the child exits on its own
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.kill()
        self.proc = self.conn = None
