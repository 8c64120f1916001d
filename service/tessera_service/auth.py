"""Bearer-token authentication (tokens from Settings.api_tokens)."""
from __future__ import annotations

import hmac

from fastapi import Depends, HTTPException, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

_bearer = HTTPBearer(auto_error=False, description="a token from TESSERA_API_TOKENS")


def require_token(request: Request,
                  credentials: HTTPAuthorizationCredentials | None = Depends(_bearer)) -> None:
    tokens: list[str] = request.app.state.settings.api_tokens
    if not tokens:
        return  # authentication is off (only allowed on loopback: see embedded.serve)
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise HTTPException(401, "this server requires a bearer token: send "
                                 "'Authorization: Bearer <token>'",
                            headers={"WWW-Authenticate": "Bearer"})
    given = credentials.credentials.encode()
    # Compare against every token in constant time, so timing reveals nothing.
    if not any(hmac.compare_digest(given, t.encode()) for t in tokens):
        raise HTTPException(401, "the bearer token is not valid",
                            headers={"WWW-Authenticate": "Bearer error=\"invalid_token\""})


def is_loopback(host: str) -> bool:
    return host in ("127.0.0.1", "::1", "localhost") or host.startswith("127.")
