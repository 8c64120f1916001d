"""Who may use the API: named users, each with one or more bearer tokens, some of them admins.

Configured from the environment (Settings.api_tokens, Settings.api_admins):

    TESSERA_API_TOKENS=alice:7f3c...,bob:91ab...,ci:04de...
    TESSERA_API_ADMINS=alice

A user sees and controls only the jobs they submitted; an admin sees every job. An entry
without a user name (the older `TESSERA_API_TOKENS=tok1,tok2` form) is a token of the
user `default`, so such a server keeps working with one shared user.
"""
from __future__ import annotations

import hashlib
import hmac
import re
from dataclasses import dataclass

# Names end up in Redis keys and logs: keep them to a plain, printable alphabet.
USER_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.@-]{0,63}")
LEGACY_USER = "default"
# The one user of a server without tokens that answers loopback requests by explicit
# setting (Settings.allow_anonymous_loopback): whoever runs it owns the machine.
LOCAL_USER = "local"


class UserConfigError(ValueError):
    """The token configuration is unusable; the message names the offending entry."""


@dataclass(frozen=True)
class User:
    name: str
    admin: bool = False

    def may_see(self, owner: str | None) -> bool:
        """Whether this user may see a job owned by `owner` (None: a job submitted before
        jobs had owners, which only admins see)."""
        return self.admin or (owner is not None and owner == self.name)


class UserDirectory:
    """Tokens -> users. Tokens are kept only as SHA-256 digests and compared in constant
    time against every entry, so neither memory dumps of the settings object nor the
    timing of a refusal say which token was close."""

    def __init__(self, entries: list[str], admins: list[str] = ()):
        self._tokens: list[tuple[bytes, User]] = []
        admins = set(admins)
        for name in admins:
            if not USER_NAME.fullmatch(name):
                raise UserConfigError(f"TESSERA_API_ADMINS: {name!r} is not a valid user name "
                                      f"(letters, digits, '_', '.', '@', '-'; at most 64)")
        seen: dict[bytes, str] = {}
        for position, entry in enumerate(entries, 1):
            name, sep, token = entry.partition(":")
            if not sep:
                name, token = LEGACY_USER, entry
            if not USER_NAME.fullmatch(name):
                raise UserConfigError(f"TESSERA_API_TOKENS entry {position}: {name!r} is not a "
                                      f"valid user name (write user:token)")
            if not token:
                raise UserConfigError(f"TESSERA_API_TOKENS entry {position} (user {name}) has "
                                      f"an empty token")
            digest = hashlib.sha256(token.encode()).digest()
            if digest in seen and seen[digest] != name:
                raise UserConfigError(f"TESSERA_API_TOKENS entry {position}: user {name} has the "
                                      f"same token as user {seen[digest]}")
            seen[digest] = name
            self._tokens.append((digest, User(name, admin=name in admins)))
        unknown = admins - {user.name for _, user in self._tokens}
        if unknown and self._tokens:
            raise UserConfigError(f"TESSERA_API_ADMINS names users without a token: "
                                  f"{', '.join(sorted(unknown))}")

    def __bool__(self) -> bool:
        return bool(self._tokens)

    @property
    def names(self) -> list[str]:
        return sorted({user.name for _, user in self._tokens})

    def authenticate(self, token: str) -> User | None:
        given = hashlib.sha256(token.encode()).digest()
        found = None
        for digest, user in self._tokens:  # no early exit: the time does not depend on the match
            if hmac.compare_digest(given, digest):
                found = user
        return found
