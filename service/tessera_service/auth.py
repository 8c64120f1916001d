"""Bearer-token authentication, failing closed: every request but the public paths
(/healthz, the API docs) is made by a User (tessera_service.users) named by its token.

AuthGate decides before anything reads the request body, so an unauthenticated upload is
refused after its headers (without it, FastAPI received a 200 MB body in full before the
dependency said 401).

A server without tokens answers nobody, unless Settings.allow_anonymous_loopback says so
explicitly (`tessera serve` sets it for its embedded single-machine farm); even then only a
request whose both ends are loopback addresses is served, and a request that carries
Forwarded / X-Forwarded-For / X-Real-IP is taken to come from wherever those say, when the
peer is a configured trusted proxy, and from elsewhere (refused) when it is not. A TLS
proxy on the same host connects over loopback: inferring "local" from the socket alone
served the world when the tokens were forgotten.

Such an anonymous request must also be addressed to this machine by a name in
Settings.allowed_hosts (its Host header; loopback IP addresses always do), and one that
changes something (any method but GET, HEAD, OPTIONS) must not come from a page of another
origin (its Origin header). Otherwise any web page its user visits could submit jobs
(a cross-site form or fetch: the browser sends it from this machine) and, by rebinding its
own DNS name to 127.0.0.1, read them. A request with a token needs neither check: a browser
never attaches a bearer token by itself.
"""
from __future__ import annotations

import ipaddress
import logging
import re

from fastapi import Depends, HTTPException, Request
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from starlette.types import ASGIApp, Receive, Scope, Send

from .users import LOCAL_USER, User, UserDirectory

log = logging.getLogger("tessera.service.auth")

_bearer = HTTPBearer(auto_error=False, description="a token from TESSERA_API_TOKENS")
PUBLIC_PATHS = frozenset({"/healthz", "/openapi.json",
                          # the API's docs page and its Swagger UI files (routers/apidocs.py)
                          "/docs", "/docs/oauth2-redirect", "/docs/swagger-ui-bundle.js",
                          "/docs/swagger-ui.css", "/docs/favicon-32x32.png",
                          # the monitor page (routers/monitor.py): static, holds no data
                          "/", "/monitor/monitor.js", "/monitor/monitor.css"})
SCOPE_KEY = "tessera.user"
FORWARDING_HEADERS = (b"forwarded", b"x-forwarded-for", b"x-real-ip")
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

Address = ipaddress.IPv4Address | ipaddress.IPv6Address
Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def require_user(request: Request,
                 credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> User:
    """The user AuthGate authenticated (`credentials` is declared only so that the OpenAPI
    schema shows the bearer scheme)."""
    user = request.scope.get(SCOPE_KEY)
    if not isinstance(user, User):  # a route reached without the gate: refuse, never guess
        raise HTTPException(401, "this server requires a bearer token: send "
                                 "'Authorization: Bearer <token>'",
                            headers={"WWW-Authenticate": "Bearer"})
    return user


class AuthGate:
    """ASGI middleware: authenticates every HTTP request outside PUBLIC_PATHS from its
    headers alone and answers 401/403 without ever calling `receive`."""

    def __init__(self, app: ASGIApp, users: UserDirectory, *, allow_anonymous_loopback: bool,
                 trusted_proxies: list[Network],
                 allowed_hosts: list[str] = ("localhost", "127.0.0.1", "::1")):
        self.app, self.users = app, users
        self.allow_anonymous_loopback = allow_anonymous_loopback
        self.trusted_proxies = trusted_proxies
        self.allowed_hosts = frozenset(_normal_host(h) for h in allowed_hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        # Only HTTP is served (no websocket routes); require_user refuses anything that
        # reaches a route without passing here.
        if scope["type"] != "http" or scope["path"] in PUBLIC_PATHS:
            await self.app(scope, receive, send)
            return
        try:
            scope[SCOPE_KEY] = self.authenticate(scope)
        except HTTPException as refused:
            response = JSONResponse({"detail": refused.detail}, status_code=refused.status_code,
                                    headers=refused.headers)
            await response(scope, receive, send)
            return
        await self.app(scope, receive, send)

    def authenticate(self, scope: Scope) -> User:
        headers = _headers(scope)
        if not self.users:
            return self._anonymous(scope, headers)
        scheme, _, token = headers.get(b"authorization", b"").decode("latin-1").partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise HTTPException(401, "this server requires a bearer token: send "
                                     "'Authorization: Bearer <token>'",
                                headers={"WWW-Authenticate": "Bearer"})
        user = self.users.authenticate(token.strip())
        if user is None:
            raise HTTPException(401, "the bearer token is not valid",
                                headers={"WWW-Authenticate": "Bearer error=\"invalid_token\""})
        return user

    def _anonymous(self, scope: Scope, headers: dict[bytes, bytes]) -> User:
        if not self.allow_anonymous_loopback:
            raise HTTPException(401, "this server has no API tokens, and anonymous access is "
                                     "off: set TESSERA_API_TOKENS (user:token pairs), or "
                                     "TESSERA_ALLOW_ANONYMOUS_LOOPBACK=1 for a server only "
                                     "this machine's users reach",
                                headers={"WWW-Authenticate": "Bearer"})
        local = _address(scope.get("server"))
        if local is None or not local.is_loopback:
            raise HTTPException(403, f"this server has no API tokens, so it only answers on "
                                     f"loopback addresses, and this request arrived on "
                                     f"{_shown(scope.get('server'))}: set TESSERA_API_TOKENS "
                                     f"to serve other hosts")
        origin = self.client_address(scope, headers)
        if origin is None or not origin.is_loopback:
            raise HTTPException(403, f"this server has no API tokens, so it only answers "
                                     f"requests from this machine, and this one came from "
                                     f"{origin or 'an unknown address'} (through a proxy, or "
                                     f"an untrusted one): set TESSERA_API_TOKENS")
        self._check_addressed_here(scope, headers)
        return User(LOCAL_USER, admin=True)

    def _check_addressed_here(self, scope: Scope, headers: dict[bytes, bytes]) -> None:
        """Refuses an anonymous request that a web page may have made (module docstring)."""
        raw = headers.get(b"host")  # (none: HTTP/1.0, never a browser)
        host = _host_of(raw.decode("latin-1")) if raw is not None else ""
        if raw is not None and not self._host_allowed(host):
            raise HTTPException(403, f"this server has no API tokens, so it only answers "
                                     f"requests addressed to this machine by name "
                                     f"(TESSERA_ALLOWED_HOSTS: {', '.join(sorted(self.allowed_hosts))}, "
                                     f"or a loopback address), and this one was addressed to "
                                     f"{host[:100] or 'no host'!r}: a web page rebinding its name "
                                     f"to this machine looks like that")
        if scope.get("method") in SAFE_METHODS:
            return
        origin = headers.get(b"origin")
        if origin is None:
            return  # not a browser's cross-origin request: they always send Origin
        origin_host = _host_of(origin.decode("latin-1"), url=True)
        if not self._host_allowed(origin_host):
            raise HTTPException(403, f"this server has no API tokens, so it refuses a change "
                                     f"requested by a web page of another site (Origin: "
                                     f"{origin.decode('latin-1')[:100]!r}): submit from the "
                                     f"command line, or from a page served by this server")

    def _host_allowed(self, host: str) -> bool:
        if not host:
            return False
        if host in self.allowed_hosts or "*" in self.allowed_hosts:
            return True
        address = _ip(host)
        return address is not None and address.is_loopback

    def client_address(self, scope: Scope, headers: dict[bytes, bytes]) -> Address | None:
        """Where the request came from: the peer, or, when the peer is a trusted proxy,
        the nearest address in its forwarding headers that is not a trusted proxy. None
        when unknown, including forwarding headers from an untrusted peer (a direct
        client can write anything there; a proxy that is not trusted says nothing)."""
        peer = _address(scope.get("client"))
        forwarded = [h for h in FORWARDING_HEADERS if h in headers]
        if not forwarded:
            return peer
        if peer is None or not self._trusted(peer) or len(forwarded) > 1:
            return None  # (two kinds of forwarding header: which one is the proxy's?)
        chain = _forwarding_chain(headers, forwarded[0])
        if chain is None:  # present but unparsable ("unknown", obfuscated, garbage)
            return None
        for hop in reversed(chain):  # the right end was written by the proxy nearest us
            if not self._trusted(hop):
                return hop
        return chain[0] if chain else None

    def _trusted(self, address: Address) -> bool:
        return any(address in network for network in self.trusted_proxies)


def parse_networks(entries: list[str]) -> list[Network]:
    """Trusted proxies as given in the settings: addresses or CIDR networks."""
    networks = []
    for entry in entries:
        try:
            networks.append(ipaddress.ip_network(entry, strict=False))
        except ValueError:
            raise ValueError(f"TESSERA_TRUSTED_PROXIES: {entry!r} is not an IP address or "
                             f"network") from None
    return networks


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "::1", "localhost") or host.startswith("127.")


def _headers(scope: Scope) -> dict[bytes, bytes]:
    """Header names -> values; repeated headers are joined with commas (RFC 9110), so
    that a second X-Forwarded-For line cannot hide from the chain."""
    out: dict[bytes, bytes] = {}
    for name, value in scope.get("headers", ()):
        name = name.lower()
        out[name] = out[name] + b", " + value if name in out else value
    return out


def _address(endpoint) -> Address | None:
    """An (host, port) pair's host as an IP address (IPv4-mapped IPv6 as IPv4); None for
    anything else: a Unix socket, an in-process client, an unparsable host."""
    if not endpoint:
        return None
    return _ip(str(endpoint[0]))


def _ip(text: str) -> Address | None:
    try:
        address = ipaddress.ip_address(text.split("%")[0])
    except ValueError:
        return None
    return getattr(address, "ipv4_mapped", None) or address


def _shown(endpoint) -> str:
    return str(endpoint[0]) if endpoint else "an unknown address"


_FOR = re.compile(r'for=("?)([^";,]*)\1', re.IGNORECASE)


def _forwarding_chain(headers: dict[bytes, bytes], name: bytes) -> list[Address] | None:
    """The client addresses header `name` lists, nearest the client first; None if any
    entry is not an IP address."""
    value = headers[name].decode("latin-1")
    chain: list[str] = []
    if name == b"forwarded":
        for element in value.split(","):
            match = _FOR.search(element)
            if match is None:
                return None
            chain.append(match.group(2))
    else:
        chain = value.split(",")
    addresses = [_ip(_strip_port(hop)) for hop in chain]
    return None if any(a is None for a in addresses) else addresses


def _normal_host(host: str) -> str:
    """'LOCALHOST.' -> 'localhost', '[::1]' -> '::1'."""
    host = host.strip().lower().rstrip(".")
    return host[1:-1] if host.startswith("[") and host.endswith("]") else host


def _host_of(value: str, *, url: bool = False) -> str:
    """The host name of a Host header ('name:port', '[v6]:port') or of an Origin
    ('scheme://name:port'; 'null' has none): '' when there is none or it is malformed."""
    if url:
        scheme, sep, rest = value.strip().partition("://")
        if not sep or not scheme:
            return ""
        value = rest
    value = value.strip()
    if not value or any(c in value for c in "/@?#\\ "):
        return ""
    if value.startswith("["):
        host, bracket, port = value[1:].partition("]")
        if not bracket or (port and not (port.startswith(":") and port[1:].isdigit())):
            return ""
    elif value.count(":") == 1:
        host, _, port = value.partition(":")
        if not port.isdigit():
            return ""
    elif ":" in value:
        return ""
    else:
        host = value
    return _normal_host(host)


def _strip_port(hop: str) -> str:
    """'[2001:db8::1]:4711' -> '2001:db8::1', '192.0.2.1:80' -> '192.0.2.1'."""
    hop = hop.strip()
    if hop.startswith("["):
        return hop[1:].split("]", 1)[0]
    if hop.count(":") == 1:
        return hop.split(":", 1)[0]
    return hop
