"""How long a stopping worker keeps rendering its current task.

A stop request (SIGTERM from systemd, Docker or Kubernetes) lets the task being rendered
finish, but an orchestrator kills the process once its own grace period is over
(Kubernetes' terminationGracePeriodSeconds, Docker's stop timeout). A task cut off by that
kill stays pending under a dead worker until its heartbeat expires and a reaper claims it.
So the worker keeps rendering only for `budget` seconds after the stop request; a task that
is not done by then is handed back to its queue (hand_back.lua), where another worker takes
it at once, and the worker exits cleanly inside the orchestrator's grace period."""
from __future__ import annotations

import threading
import time


class HandBack(Exception):
    """The worker is stopping and its stop budget ran out before the task was done."""


class StopGrace:
    """Measures the stop budget from the first time a render sees the stop request.

    The render loop looks every CANCEL_POLL seconds, so the budget starts at most that much
    after the request itself; the orchestrator's grace period must leave room for it, for
    handing the task back and for the worker's exit (deploy/k8s/worker.yaml)."""

    def __init__(self, budget: float):
        self.budget = budget
        self._since: float | None = None

    def check(self, stop: threading.Event | None) -> None:
        """Raises HandBack once `stop` has been set for longer than the budget."""
        if stop is None or not stop.is_set():
            return
        now = time.monotonic()
        if self._since is None:
            self._since = now
        if now - self._since >= self.budget:
            raise HandBack()
