"""Authentication fails closed, against real uvicorn / `tessera serve` processes and a real
redis-server: no tokens serves nobody unless anonymous loopback access is set explicitly;
forwarding headers count only from trusted proxies; an unauthenticated upload is refused
from its headers, before its body is sent."""
from __future__ import annotations

import socket
import sys

import httpx
import pytest

from conftest import STARTUP_TIMEOUT, Process, clean_env, start_api, wait_until_ready
from tessera_cli.embedded import free_port

TOKEN = "tok-alice-1"
ELSEWHERE = "203.0.113.7"  # TEST-NET-3: some host on the internet


def test_no_tokens_serves_nobody_without_the_explicit_setting(redis_server, tmp_path):
    """Before: a loopback request was served without a token whenever TESSERA_API_TOKENS
    was empty. Now that needs TESSERA_ALLOW_ANONYMOUS_LOOPBACK; /healthz stays open."""
    api, base = start_api(redis_server, tmp_path, allow_anonymous_loopback="0")
    try:
        assert httpx.get(f"{base}/healthz").status_code == 200
        for path in ("/jobs", "/workers", "/metrics", "/jobs/" + "0" * 32):
            r = httpx.get(f"{base}{path}")
            assert r.status_code == 401, (path, r.text)
            detail = r.json()["detail"]
            assert "TESSERA_API_TOKENS" in detail and "TESSERA_ALLOW_ANONYMOUS_LOOPBACK" in detail
    finally:
        api.stop()
    assert "every request but /healthz is refused" in api.log()


def test_anonymous_loopback_refuses_whatever_a_proxy_forwarded(redis_server, tmp_path):
    """With anonymous loopback access on and no trusted proxies, a request that carries any
    forwarding header came through a proxy (a TLS proxy on this host connects over
    loopback) or forged one: refused either way. (Before: all served.)"""
    api, base = start_api(redis_server, tmp_path)  # allow_anonymous_loopback=1
    try:
        assert httpx.get(f"{base}/jobs").status_code == 200  # the control: plain loopback
        for header, value in (("X-Forwarded-For", ELSEWHERE), ("Forwarded", f"for={ELSEWHERE}"),
                              ("X-Real-IP", ELSEWHERE), ("X-Forwarded-For", "127.0.0.1"),
                              ("Forwarded", 'for="[::1]:4711"')):
            r = httpx.get(f"{base}/jobs", headers={header: value})
            assert r.status_code == 403, (header, value, r.text)
            assert "TESSERA_API_TOKENS" in r.json()["detail"]
    finally:
        api.stop()


def _serve(tmp_path, redis_url: str, *args: str, **env: str) -> tuple[Process, str]:
    """`tessera serve` against an existing Redis (the deployment form; it does not rewrite
    the peer address from headers, unlike a bare uvicorn)."""
    port = free_port()
    proc = Process(f"serve-{port}", [sys.executable, "-m", "tessera", "serve", "--port", str(port),
                                     "--redis-url", redis_url, *args], tmp_path,
                   clean_env(**{f"TESSERA_{k.upper()}": v for k, v in env.items()}))
    base = f"http://127.0.0.1:{port}"
    wait_until_ready(proc, base)
    return proc, base


def test_serve_with_a_redis_url_needs_tokens_or_insecure_local(redis_server, tmp_path):
    """The deployment form of `tessera serve` infers nothing: without tokens it refuses
    even loopback, unless --insecure-local says so."""
    proc, base = _serve(tmp_path, redis_server)
    try:
        assert httpx.get(f"{base}/jobs").status_code == 401
    finally:
        proc.stop()
    proc, base = _serve(tmp_path, redis_server, "--insecure-local")
    try:
        assert httpx.get(f"{base}/jobs").status_code == 200
    finally:
        proc.stop()


@pytest.mark.parametrize("chain, served", [
    ("127.0.0.1", True),                          # a local user through the local proxy
    (ELSEWHERE, False),                           # the world through the local proxy
    (f"{ELSEWHERE}, 127.0.0.1", False),           # the nearest untrusted hop is the client
    (f"127.0.0.1, {ELSEWHERE}", False),           # a forged first entry does not help
    ("unknown", False),                           # unparsable: origin unknown
])
def test_forwarding_headers_count_only_from_trusted_proxies(redis_server, tmp_path, chain, served):
    proc, base = _serve(tmp_path, redis_server, "--insecure-local",
                        trusted_proxies="127.0.0.1/32")
    try:
        r = httpx.get(f"{base}/jobs", headers={"X-Forwarded-For": chain})
        assert r.status_code == (200 if served else 403), r.text
    finally:
        proc.stop()


def _upload_head(port: int, path: str, token: str | None, length: int, expect: bool) -> bytes:
    """Sends only the headers of a `length`-byte multipart upload and returns the first
    bytes the server answers (the test waits for that answer, not for a time)."""
    lines = [f"POST {path} HTTP/1.1", f"Host: 127.0.0.1:{port}",
             "Content-Type: multipart/form-data; boundary=b", f"Content-Length: {length}"]
    if token:
        lines.append(f"Authorization: Bearer {token}")
    if expect:
        lines.append("Expect: 100-continue")
    with socket.create_connection(("127.0.0.1", port), timeout=STARTUP_TIMEOUT) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        return s.recv(4096)


@pytest.mark.parametrize("path", ["/jobs", "/compare"])
def test_an_unauthenticated_upload_is_refused_before_its_body_is_sent(redis_server, tmp_path, path):
    """200 MB announced, not one body byte sent: the 401 arrives anyway. Before, the route's
    dependency ran after FastAPI had read the whole body, so this waited for a body that
    never came (the socket timeout failed the test). With Expect: 100-continue the server
    never asks for the body, while for a valid token it does (the control)."""
    api, base = start_api(redis_server, tmp_path, api_tokens=f"alice:{TOKEN}",
                          max_upload_bytes=str(256 << 20))
    port = int(base.rsplit(":", 1)[1])
    try:
        for token in (None, "wrong-token"):
            for expect in (False, True):
                answer = _upload_head(port, path, token, 200 << 20, expect)
                assert answer.startswith(b"HTTP/1.1 401 "), (token, expect, answer)
        assert _upload_head(port, path, TOKEN, 200 << 20, True).startswith(b"HTTP/1.1 100 ")
    finally:
        api.stop()


@pytest.mark.parametrize("server, client", [
    (("testserver", 80), ("127.0.0.1", 5000)),    # an unparsable server address (was allowed)
    (None, ("127.0.0.1", 5000)),                  # no server address (a Unix socket)
    (("127.0.0.1", 8000), None),                  # no peer address
    (("127.0.0.1", 8000), ("192.0.2.9", 5000)),   # a remote peer on a loopback listener (NAT)
    (("::ffff:10.0.0.1", 8000), ("127.0.0.1", 5000)),
])
def test_anonymous_access_needs_two_loopback_addresses(server, client):
    """The gate itself, on the scopes a server may hand it: whatever is not provably
    loopback at both ends is refused (control: both loopback is served)."""
    from fastapi import HTTPException

    from tessera_service.auth import AuthGate
    from tessera_service.users import UserDirectory

    gate = AuthGate(None, UserDirectory([]), allow_anonymous_loopback=True, trusted_proxies=[])
    with pytest.raises(HTTPException) as refused:
        gate.authenticate({"type": "http", "headers": [], "server": server, "client": client})
    assert refused.value.status_code == 403
    served = gate.authenticate({"type": "http", "headers": [], "server": ("127.0.0.1", 8000),
                                "client": ("::1", 5000)})
    assert served.name == "local" and served.admin
