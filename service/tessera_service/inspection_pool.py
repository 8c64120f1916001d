"""A bounded pool of scene inspections across all uploads of one API process.

Each inspection may use up to Settings.preflight_memory_bytes; without a bound, parallel
uploads of different hostile scenes multiplied that (two took 11 GB). At most `running`
inspections run at once, at most `waiting` more wait for a slot (for up to `wait_seconds`),
and any beyond that are refused at once with 429 and Retry-After, so that the memory an
API host needs is `running` x the pre-flight memory, whatever clients send.
"""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager


class PoolFull(Exception):
    """No slot now and no room to wait; the message is meant for the client."""


class InspectionPool:
    def __init__(self, running: int, waiting: int, wait_seconds: float,
                 activity: str = "inspecting {n} other scene(s)"):
        self.activity = activity
        self.capacity, self.queue_capacity, self.wait_seconds = running, waiting, wait_seconds
        self._cond = threading.Condition()
        self.running = 0
        self.waiting = 0

    @contextmanager
    def slot(self):
        with self._cond:
            if self.running >= self.capacity:
                if self.waiting >= self.queue_capacity:
                    raise PoolFull(self._busy(f"and {self.waiting} more are waiting"))
                self.waiting += 1
                try:
                    deadline = time.monotonic() + self.wait_seconds
                    while self.running >= self.capacity:
                        left = deadline - time.monotonic()
                        if left <= 0:
                            raise PoolFull(self._busy(f"for longer than {self.wait_seconds:g} s"))
                        self._cond.wait(left)
                finally:
                    self.waiting -= 1
            self.running += 1
        try:
            yield
        finally:
            with self._cond:
                self.running -= 1
                self._cond.notify()

    def _busy(self, what: str) -> str:
        return (f"the server is {self.activity.format(n=self.running)} already, {what}: "
                f"try again shortly")
