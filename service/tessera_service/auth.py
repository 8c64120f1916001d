"""Bearer-token authentication: every request but /healthz is made by a User
(tessera_service.users) named by its token."""
from __future__ import annotations

import ipaddress

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .users import LOCAL_USER, User, UserDirectory

_bearer = HTTPBearer(auto_error=False, description="a token from TESSERA_API_TOKENS")


def require_user(request: Request,
                 credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> User:
    users: UserDirectory = request.app.state.users
    if not users:
        # Authentication is off, which is allowed only on loopback. `tessera serve` refuses
        # to bind elsewhere without tokens; this also covers any other launcher (a bare
        # `uvicorn --host 0.0.0.0`): a request that reached us through a non-loopback
        # address is refused, whatever the server was told.
        local = _local_address(request)
        if local is not None and not local.is_loopback:
            raise HTTPException(403, f"this server has no API tokens, so it only answers on "
                                     f"loopback addresses, and this request arrived on {local}: "
                                     f"set TESSERA_API_TOKENS to serve other hosts")
        return User(LOCAL_USER, admin=True)
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise HTTPException(401, "this server requires a bearer token: send "
                                 "'Authorization: Bearer <token>'",
                            headers={"WWW-Authenticate": "Bearer"})
    user = users.authenticate(credentials.credentials)
    if user is None:
        raise HTTPException(401, "the bearer token is not valid",
                            headers={"WWW-Authenticate": "Bearer error=\"invalid_token\""})
    return user


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "::1", "localhost") or host.startswith("127.")


def _local_address(request: Request) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    """The address of our end of the connection; None for transports without one (a Unix
    socket, an in-process test client), which no other host can reach."""
    server = request.scope.get("server")
    if not server:
        return None
    try:
        address = ipaddress.ip_address(str(server[0]).split("%")[0])
    except ValueError:
        return None
    mapped = getattr(address, "ipv4_mapped", None)
    return mapped or address
