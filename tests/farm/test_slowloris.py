"""Slowloris against `tessera serve` (issue 42, item 9): uvicorn held every connection that
never completed its headers (10,000 held; at ~20,000 accept failed and asyncio logged
274,431 tracebacks in 30 s). Real `tessera serve` process on a test redis-server, loopback
sockets only, a bounded number of them: connections that send nothing, part of a request's
headers, or its headers a byte at a time are closed after the header timeout while a normal
request succeeds; beyond the connection cap new connections get 503 at once; each condition
is one log line, not one per connection."""
from __future__ import annotations

import selectors
import socket
import sys
import time

import httpx
import pytest

from conftest import Process, clean_env, wait_until_ready
from tessera_cli.embedded import free_port

HEADER_TIMEOUT = 4.0   # seconds (TESSERA_HTTP_HEADER_TIMEOUT of the server under test)
BODY_IDLE_TIMEOUT = 3.0  # TESSERA_HTTP_BODY_IDLE_TIMEOUT
CAP = 150              # TESSERA_HTTP_MAX_CONNECTIONS
CLOSE_BOUND = 60.0     # the test gives up waiting for the server to close a socket after this
PARTIAL = b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: "


@pytest.fixture(scope="module")
def server(redis_server, tmp_path_factory):
    port = free_port()
    proc = Process(f"serve-{port}", [sys.executable, "-m", "tessera", "serve", "--port", str(port),
                                     "--workers", "0", "--redis-url", redis_server,
                                     "--insecure-local"],
                   tmp_path_factory.mktemp("serve"),
                   clean_env(TESSERA_HTTP_HEADER_TIMEOUT=str(HEADER_TIMEOUT),
                             TESSERA_HTTP_BODY_IDLE_TIMEOUT=str(BODY_IDLE_TIMEOUT),
                             TESSERA_HTTP_MAX_CONNECTIONS=str(CAP)))
    wait_until_ready(proc, f"http://127.0.0.1:{port}")
    yield proc, port
    proc.stop()


def _open(port: int, n: int, payload: bytes) -> list[socket.socket]:
    socks = []
    for _ in range(n):
        s = socket.create_connection(("127.0.0.1", port), timeout=5)
        if payload:
            s.sendall(payload)
        socks.append(s)
    return socks


def _wait_closed(socks: list[socket.socket]) -> dict[socket.socket, bytes]:
    """Reads every socket until the server closes it (EOF or reset); returns what each
    received. Fails if any is still open after CLOSE_BOUND seconds."""
    received = {s: b"" for s in socks}
    sel = selectors.DefaultSelector()
    for s in socks:
        s.setblocking(False)
        sel.register(s, selectors.EVENT_READ)
    open_ = set(socks)
    deadline = time.monotonic() + CLOSE_BOUND
    while open_ and time.monotonic() < deadline:
        for key, _ in sel.select(timeout=1.0):
            s = key.fileobj
            try:
                data = s.recv(65536)
            except ConnectionResetError:
                data = b""
            if data:
                received[s] += data
            else:
                sel.unregister(s)
                open_.discard(s)
    sel.close()
    for s in socks:
        s.close()
    assert not open_, f"{len(open_)} of {len(socks)} connections still open after {CLOSE_BOUND} s"
    return received


def _trickle(port: int) -> int:
    """Sends request headers one byte at a time, never finishing them (each byte resets
    uvicorn's own keep-alive timer); returns how many bytes went out before the server
    closed the connection."""
    s = socket.create_connection(("127.0.0.1", port), timeout=5)
    sent = 0
    try:
        for byte in PARTIAL + b"x" * 1000:
            s.sendall(bytes([byte]))
            sent += 1
            s.settimeout(0.25)  # paces the bytes: a read that waits for the close
            try:
                if s.recv(1) == b"":
                    return sent
            except TimeoutError:
                pass
            except ConnectionResetError:
                return sent
    except (BrokenPipeError, ConnectionResetError):
        return sent
    finally:
        s.close()
    return sent


def test_idle_and_slow_connections_are_closed_while_requests_succeed(server):
    proc, port = server
    silent = _open(port, 50, b"")
    partial = _open(port, 50, PARTIAL)
    # 100 connections held open: a normal request is still served.
    r = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=10)
    assert r.status_code == 200, r.text
    received = _wait_closed(silent + partial)
    assert all(not data for data in received.values())  # closed, not answered
    # A byte every 0.25 s keeps uvicorn's keep-alive timer from ever firing; the header
    # timeout still closes it, long before the 1,050 bytes run out.
    assert _trickle(port) < len(PARTIAL) + 1000
    log = proc.log_path.read_text(errors="replace")
    assert "Traceback" not in log
    assert 1 <= log.count("sent no complete request headers") <= 2, log[-3000:]


def test_connections_beyond_the_cap_get_503_until_the_held_ones_time_out(server):
    proc, port = server
    held = _open(port, CAP, PARTIAL)
    extra = _open(port, 50, b"")
    r = httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=10)
    assert r.status_code == 503 and r.headers.get("retry-after") == "5", r.text
    received = _wait_closed(held + extra)
    assert all(data.startswith(b"HTTP/1.1 503") for s, data in received.items() if s in extra)
    assert all(not received[s] for s in held)
    # The held connections timed out: the server answers again.
    assert httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=10).status_code == 200
    log = proc.log_path.read_text(errors="replace")
    assert log.count("new ones get 503") == 1 and "Traceback" not in log, log[-3000:]


def test_a_stalled_request_body_is_closed(server):
    proc, port = server
    head = (b"POST /jobs HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            b"Content-Type: multipart/form-data; boundary=b\r\nContent-Length: 1000\r\n\r\n")
    stalled = _open(port, 20, head + b"--b\r\n")  # 6 of 1,000 bytes, then nothing
    received = _wait_closed(stalled)
    # Closed by the server without an answer (the app saw a disconnect, not a body).
    assert all(not data for data in received.values()), set(received.values())
    log = proc.log_path.read_text(errors="replace")
    assert log.count("request body stalled") == 1 and "Traceback" not in log, log[-3000:]


def test_failed_accepts_are_one_log_line_a_minute(caplog):
    """asyncio reports each failed accept (EMFILE) to the loop's exception handler with a
    traceback; the API's handler turns a burst of them into one line."""
    import asyncio
    import errno

    from tessera_service.http_guard import accept_error_handler

    loop = asyncio.new_event_loop()
    try:
        with caplog.at_level("WARNING"):
            for _ in range(1000):
                accept_error_handler(loop, {"message": "socket.accept() out of system resource",
                                            "exception": OSError(errno.EMFILE, "Too many open files")})
            # Anything else still reaches asyncio's default handler (logged with its message).
            accept_error_handler(loop, {"message": "something else broke"})
    finally:
        loop.close()
    lines = [r.getMessage() for r in caplog.records]
    assert sum("accepting connections fails" in m for m in lines) == 1, lines
    assert any("something else broke" in m for m in lines), lines
