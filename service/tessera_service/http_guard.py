"""Connection limits uvicorn lacks: a header timeout, a body idle timeout and a cap on open
connections, for `tessera serve` (embedded.serve).

Uvicorn (0.55, h11) times out only an idle keep-alive connection, and only until its first
byte arrives: a client that opens a connection and never completes its request headers
(slowloris) holds a file descriptor for ever. 10,000 such connections were held; at about
20,000 the API reached its descriptor limit, every accept failed, and asyncio logged a
traceback per failed accept (274,431 in 30 s, 123 MB of log). Its `limit_concurrency`
answers 503 only to a request that has arrived, so it closes none of them either.

GuardedH11Protocol closes a connection whose request headers are not complete within
`header_timeout` seconds of its first byte (or of its opening), and one whose request body
receives no byte for `body_idle_timeout` seconds (unless the server itself stopped
reading: flow control); beyond `max_connections` open connections, a new one gets 503 and
is closed at once, so that descriptors stay below the process's limit. Each condition is
logged once per minute with a count (ConditionLog), as are failed accepts
(accept_error_handler), instead of a line or a traceback each.
"""
from __future__ import annotations

import asyncio
import logging
import resource
import time

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

log = logging.getLogger("tessera.http")

LOG_INTERVAL = 60.0  # seconds between two lines about one condition
# Descriptors kept free of connections: Redis pools, upload files, inspection pipes.
RESERVED_DESCRIPTORS = 256
_BUSY_TEXT = b"too many open connections: try again later"
BUSY = (b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: text/plain\r\nconnection: close\r\n"
        b"retry-after: 5\r\ncontent-length: %d\r\n\r\n%s" % (len(_BUSY_TEXT), _BUSY_TEXT))


class ConditionLog:
    """One log line per condition and minute: the first occurrence at once, then how many
    more there were, at the next occurrence after LOG_INTERVAL."""

    def __init__(self) -> None:
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def __call__(self, condition: str, message: str) -> None:
        now = time.monotonic()
        last = self._last.get(condition)
        if last is not None and now - last < LOG_INTERVAL:
            self._suppressed[condition] = self._suppressed.get(condition, 0) + 1
            return
        more = self._suppressed.pop(condition, 0)
        self._last[condition] = now
        log.warning("%s%s", message,
                    f" ({more} more times in the last {now - last:.0f} s)" if more else "")


conditions = ConditionLog()


def connection_cap(wanted: int) -> int:
    """`wanted`, lowered to what the process's descriptor limit allows (after raising its
    soft limit to the hard one)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and soft < hard:
        try:
            resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
            soft = hard
        except (ValueError, OSError):
            pass
    if soft == resource.RLIM_INFINITY:
        return wanted
    return max(1, min(wanted, soft - RESERVED_DESCRIPTORS))


def guarded_protocol(header_timeout: float, body_idle_timeout: float, max_connections: int) -> type:
    """An H11Protocol class with these limits, for uvicorn.Config(http=...)."""

    class GuardedH11Protocol(H11Protocol):
        _timer: asyncio.TimerHandle | None = None
        _waiting_for: str | None = None  # "headers" or "body": what the timer guards

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            if len(self.connections) > max_connections:
                conditions("cap", f"{max_connections} connections open "
                                  f"(TESSERA_HTTP_MAX_CONNECTIONS): new ones get 503")
                transport.write(BUSY)
                transport.close()
                return
            self._guard()

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            self._guard(progress=True)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            self._guard()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel()
            super().connection_lost(exc)

        def _guard(self, progress: bool = False) -> None:
            """Arms, keeps or cancels the timer for what the connection waits for now."""
            if self.transport.is_closing():
                return self._cancel()
            state = self.conn.their_state
            if state is h11.IDLE and self.timeout_keep_alive_task is None:
                # Request headers under way (or a fresh connection): one deadline for all
                # of them, however slowly they trickle in.
                if self._waiting_for != "headers":
                    self._arm("headers", header_timeout)
            elif state is h11.SEND_BODY:
                if self._waiting_for != "body" or progress:
                    self._arm("body", body_idle_timeout)
            else:  # idle keep-alive (uvicorn's own timer), or the request is in
                self._cancel()

        def _arm(self, what: str, seconds: float) -> None:
            self._cancel()
            self._waiting_for = what
            self._timer = self.loop.call_later(seconds, self._expired)

        def _cancel(self) -> None:
            if self._timer is not None:
                self._timer.cancel()
            self._timer, self._waiting_for = None, None

        def _expired(self) -> None:
            what = self._waiting_for
            self._timer, self._waiting_for = None, None
            if what == "body" and self.flow.read_paused:
                # The server stopped reading (the app has not taken the body yet): not the
                # client's delay.
                return self._arm("body", body_idle_timeout)
            if what == "headers":
                conditions("headers", f"closed a connection that sent no complete request "
                                      f"headers within {header_timeout:g} s "
                                      f"(TESSERA_HTTP_HEADER_TIMEOUT)")
            else:
                conditions("body", f"closed a connection whose request body stalled for "
                                   f"{body_idle_timeout:g} s (TESSERA_HTTP_BODY_IDLE_TIMEOUT)")
            if self.cycle is not None and not self.cycle.response_complete:
                self.cycle.disconnected = True
            self.transport.close()

    return GuardedH11Protocol


def accept_error_handler(loop: asyncio.AbstractEventLoop, context: dict) -> None:
    """asyncio's exception handler, but a failed accept (out of descriptors) is one line a
    minute rather than a traceback each time."""
    if "accept" in str(context.get("message", "")):
        conditions("accept", f"accepting connections fails: {context.get('exception')!r} "
                             f"(descriptor limit {resource.getrlimit(resource.RLIMIT_NOFILE)[0]})")
        return
    loop.default_exception_handler(context)
